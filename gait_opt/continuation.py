"""Natural-parameter continuation of the reference-gait NLP in the speed (what
:func:`gait_opt.gait_family` builds a family of gaits with).

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

import dataclasses
import math
import time
from dataclasses import dataclass, field

import numpy as np

from .options import GaitOptions
from .transcription import (build_problem, constraint_violations, describe_violations,
                            initial_guess, make_solver)

__all__ = ["SpeedNLP", "NLPPoint", "Advance", "advance", "active_families",
           "describe_failure", "fold_suspected", "WARM_MAX_ITER", "MIN_STEP_FRACTION",
           "FIRST_STEP_FRACTION", "JUMP_RATIO", "FOLD_BRACKET"]

#: a warm solve taking more IPOPT iterations than this counts as a failed step (halved)
WARM_MAX_ITER = 60
#: the smallest step tried, a fraction of the requested one, before the family ends
MIN_STEP_FRACTION = 1 / 16
#: without a secant yet, the first step is this fraction of the requested one
FIRST_STEP_FRACTION = 1 / 8
#: a step whose |d theta / d v| exceeds the previous step's by this factor is checked for
#: a jump to another branch
JUMP_RATIO = 3.0
#: a fold is located to within this fraction of the requested step
FOLD_BRACKET = 1 / 4
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
    the objective ``cost`` (unscaled), the wall ``time`` of the solve and the node
    ``margins`` it was solved with."""

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
    margins: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        """IPOPT succeeded and no constraint family is violated."""
        return self.status in SUCCESS and not self.violations


class SpeedNLP:
    """The gait NLP with the speed as its parameter, with a cold and a warm IPOPT.

    The node margins of the torque limit, the normal force, the swing-foot clearance and
    the torso lean (:func:`gait_opt.optimize_gait`) shift only constraint bounds, so every
    solve takes its own; the friction cone's margin is part of the constraint and of the
    NLP.

    Parameters
    ----------
    model : BipedModel
        The robot.
    options : GaitOptions
        The problem (its ``speed`` is not used: each solve gives its own).
    friction_margin : float
        The friction cone's node margin (mu - margin at the nodes).
    verbose : bool
        Print IPOPT's iterations.
    """

    def __init__(self, model, options: GaitOptions, friction_margin: float = 0.0,
                 verbose: bool = False):
        t0 = time.perf_counter()
        self.model = model
        self.options = options.for_model(model)
        self.friction_margin = float(friction_margin)
        built = {"friction cone": self.friction_margin} if self.friction_margin else {}
        self.prob = build_problem(model, self.options, built, speed_parameter=True)
        self.cold = make_solver(self.prob, self.options, verbose)
        cap = min(WARM_MAX_ITER, int(self.options.ipopt.get("max_iter", WARM_MAX_ITER)))
        warm = {**self.options.ipopt, **WARM_IPOPT, "max_iter": cap}
        self.warm = make_solver(self.prob, self.options.replace(ipopt=warm), verbose)
        self.build_time = time.perf_counter() - t0

    def problem(self, margins: dict | None = None):
        """The transcribed problem with the bounds of these node margins.

        Parameters
        ----------
        margins : dict, optional
            Family of :data:`gait_opt.transcription.MARGINS` -> amount; the friction
            cone's must be this NLP's ``friction_margin``.

        Returns
        -------
        Problem
            ``lbg``, ``ubg`` shifted (a copy; the NLP's own when no margin is given).
        """
        margins = {k: v for k, v in (margins or {}).items() if v}
        if margins.get("friction cone", 0.0) != self.friction_margin:
            raise ValueError(f"margins: this NLP has the friction margin "
                             f"{self.friction_margin:g}, not {margins.get('friction cone')}")
        shifts = {k: v for k, v in margins.items() if k != "friction cone"}
        if not shifts:
            return self.prob
        lbg, ubg = self.prob.lbg.copy(), self.prob.ubg.copy()
        for name, a, b in self.prob.groups:
            if name in shifts:                    # both sides of a two-sided family;
                lbg[a:b] += shifts[name]          # -inf and inf stay
                ubg[a:b] -= shifts[name]
        return dataclasses.replace(self.prob, lbg=lbg, ubg=ubg)

    def _point(self, solver, speed, sol, t0, prob, margins) -> NLPPoint:
        stats = solver.stats()
        g = np.array(sol["g"]).ravel()
        return NLPPoint(
            speed=float(speed), w=np.array(sol["x"]).ravel(),
            lam_g=np.array(sol["lam_g"]).ravel(), lam_x=np.array(sol["lam_x"]).ravel(),
            g=g, status=stats.get("return_status", "unknown"),
            iterations=int(stats.get("iter_count", -1)),
            violations=constraint_violations(prob, g),
            cost=float(sol["f"]) / self.prob.cost_scale, time=time.perf_counter() - t0,
            margins=dict(margins or {}))

    def solve_cold(self, speed: float, w0=None, margins: dict | None = None) -> NLPPoint:
        """Solve at ``speed`` from the built-in guess (or a primal start ``w0``).

        Parameters
        ----------
        speed : float
            m/s.
        w0 : array_like, optional
            A decision vector to start from (IPOPT's default start otherwise).
        margins : dict, optional
            Node margins (:meth:`problem`).

        Returns
        -------
        NLPPoint
        """
        t0 = time.perf_counter()
        if w0 is None:
            w0 = initial_guess(self.model, self.options.replace(speed=float(speed)))
        prob = self.problem(margins)
        sol = self.cold(x0=w0, p=float(speed), lbx=prob.lbx, ubx=prob.ubx, lbg=prob.lbg,
                        ubg=prob.ubg)
        return self._point(self.cold, speed, sol, t0, prob, margins)

    def solve_warm(self, speed: float, start: NLPPoint,
                   margins: dict | None = None) -> NLPPoint:
        """Solve at ``speed`` from a primal-dual start (IPOPT's warm start).

        Parameters
        ----------
        speed : float
            m/s.
        start : NLPPoint
            The start: ``w``, ``lam_g``, ``lam_x`` (a predictor; its ``speed`` is not
            used).
        margins : dict, optional
            Node margins (:meth:`problem`).

        Returns
        -------
        NLPPoint
        """
        t0 = time.perf_counter()
        prob = self.problem(margins)
        w0 = np.clip(start.w, prob.lbx, prob.ubx)
        sol = self.warm(x0=w0, lam_g0=start.lam_g, lam_x0=start.lam_x, p=float(speed),
                        lbx=prob.lbx, ubx=prob.ubx, lbg=prob.lbg, ubg=prob.ubg)
        return self._point(self.warm, speed, sol, t0, prob, margins)

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
    return _distance(a, b, n_theta) / abs(b.speed - a.speed)


def _distance(a: NLPPoint, b: NLPPoint, n_theta: int) -> float:
    """max |theta_b - theta_a| (T in s, Bezier coefficients in rad)."""
    return float(np.max(np.abs(b.w[:n_theta] - a.w[:n_theta])))


@dataclass
class Advance:
    """The outcome of :func:`advance`.

    Parameters
    ----------
    point : NLPPoint or None
        The solution at the target speed (None when it was not reached).
    substeps : int
        Accepted solves.
    failed : int
        Warm solves that failed (the step halved).
    iterations : int
        IPOPT iterations over all solves.
    failure : NLPPoint or None
        The last failed solve.
    rates : list of float
        |d theta / d v| of the accepted substeps.
    time : float
        Wall time, s.
    jump : dict or None
        When the branch followed ends in a fold and the solution jumps to another
        branch: ``speed_low`` (the last speed on the branch), ``speed_high`` (the first
        on the other), ``jump`` (max |Delta theta| there), ``cost_low``, ``cost_high``,
        ``rate`` (the branch's |d theta / d v| before it); ``point`` then lies on the
        new branch (``across_folds``) or is None.
    """

    point: NLPPoint | None
    substeps: int = 0
    failed: int = 0
    iterations: int = 0
    failure: NLPPoint | None = None
    rates: list = field(default_factory=list)
    time: float = 0.0
    jump: dict | None = None

    @property
    def reached(self) -> bool:
        """The target speed was reached."""
        return self.point is not None


def _bisect(nlp, points, bad: NLPPoint, h_min, n_theta, out: Advance):
    """Is the change from the last point to ``bad`` continuous, or a jump to another
    branch?  Bisection of [last speed, bad speed]: a midpoint whose change from the last
    good point is below 0.7 of the change to the nearest point beyond is on the branch
    (appended to ``points``), else beyond.  Continuous as soon as the rate from the last
    good point to the nearest point beyond is within :data:`JUMP_RATIO` of the branch's
    last rate; a jump when the bracket is ``h_min`` wide or less.  Returns (True, [the
    point reached]) or (False, [the solutions beyond the jump, in order of speed away
    from the branch]) and the bracket's far end."""
    beyond, bad_speed = [bad], bad.speed
    while True:
        good, near = points[-1], beyond[-1]
        ref = _rate(points[-2], good, n_theta) if len(points) > 1 else math.inf
        if near.speed == bad_speed and _rate(good, near, n_theta) <= JUMP_RATIO * ref:
            return True, [near], bad_speed
        if abs(bad_speed - good.speed) <= h_min * (1 + 1e-9):
            return False, beyond[::-1], bad_speed
        mid = (good.speed + bad_speed) / 2
        q = nlp.solve_warm(mid, _predict(points, mid))
        out.iterations += q.iterations
        if not q.ok:
            out.failed += 1
            bad_speed = mid
        elif _distance(good, q, n_theta) < 0.7 * _distance(good, near, n_theta):
            out.rates.append(_rate(good, q, n_theta))
            points.append(q)
            out.substeps += 1
        else:
            beyond.append(q)
            bad_speed = mid


def advance(nlp: SpeedNLP, points: list, target: float, step: float,
            across_folds: bool = True) -> Advance:
    """Continue from the last of ``points`` to ``target`` (module docstring).

    Accepted solutions are appended to ``points`` (they feed the secant).  A step whose
    |d theta / d v| exceeds :data:`JUMP_RATIO` times the previous step's is checked by
    bisection (:func:`_bisect`): a change that does not shrink with the step, down to
    ``FOLD_BRACKET`` of ``step``, is a jump to another branch, the branch followed
    ending in a fold (``Advance.jump``).

    Parameters
    ----------
    nlp : SpeedNLP
    points : list of NLPPoint
        The solutions so far, in order of speed (at least one).
    target : float
        The speed to reach, m/s.
    step : float
        The requested step (the grid's); halving stops at ``MIN_STEP_FRACTION`` of it.
    across_folds : bool
        At a jump, continue on the other branch (``points`` restarts there); False:
        stop before it.

    Returns
    -------
    Advance
    """
    t0 = time.perf_counter()
    n_theta = 1 + nlp.model.nu * (nlp.options.bezier_degree + 1)
    h_min = abs(step) * MIN_STEP_FRACTION * (1 - 1e-9)
    h_fold = abs(step) * FOLD_BRACKET
    h = (target - points[-1].speed) * (FIRST_STEP_FRACTION if len(points) < 2 else 1.0)
    out = Advance(None)
    while abs(target - points[-1].speed) > 1e-12:
        here = points[-1].speed
        h = target - here if abs(h) >= abs(target - here) else h
        p = nlp.solve_warm(here + h, _predict(points, here + h))
        out.iterations += p.iterations
        if not p.ok:
            out.failed, out.failure, h = out.failed + 1, p, h / 2
            if abs(h) < h_min:
                break
            continue
        ref = _rate(points[-2], points[-1], n_theta) if len(points) > 1 else None
        if ref is not None and _rate(points[-1], p, n_theta) > JUMP_RATIO * ref:
            same, found, far = _bisect(nlp, points, p, h_fold, n_theta, out)
            if not same:
                last = points[-1]
                out.jump = dict(speed_low=last.speed, speed_high=far,
                                jump=_distance(last, found[0], n_theta),
                                cost_low=last.cost, cost_high=found[0].cost,
                                rate=_rate(points[-2], last, n_theta)
                                if len(points) > 1 else None)
                if not across_folds:
                    break
                # a new branch: the solutions found on it are its start and secant
                points[:] = found[-2:]
                out.substeps += 1
                h = target - points[-1].speed
                continue
            p = found[0]
            h = p.speed - points[-1].speed
        out.rates.append(_rate(points[-1], p, n_theta))
        first = len(points) == 1               # the secant exists from now on
        points.append(p)
        out.substeps += 1
        h = target - p.speed if first else 2 * h
    if abs(target - points[-1].speed) <= 1e-12:
        out.point = points[-1]
    out.time = time.perf_counter() - t0
    return out


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
    prob = nlp.problem(point.margins)
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
