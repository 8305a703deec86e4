"""The family of reference gaits over a grid of speeds: :func:`gait_family`, built by
the continuation of :mod:`gait_opt.continuation` (see :mod:`gait_opt.speed_family` for the
result and docs/theory.md, "Gait families").
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from .continuation import (MIN_STEP_FRACTION, Advance, SpeedNLP, active_families, advance,
                           describe_failure, fold_suspected)
from .errors import GaitOptimizationError
from .speed_family import SPEED_TOL, GaitFamily, MemberRecord, check_speeds
from .family_file import options_record
from .gait import Gait
from .options import GaitOptions, require_model
from .polish import polish
from .transcription import FIXED_BY, MARGINS, describe_violations, warm_start_vector

__all__ = ["gait_family"]


def _nlp_for(model, opts, state, margins):
    """The NLP of these margins: the family's, or one with their friction margin (built
    once per value)."""
    m = float(margins.get("friction cone", 0.0))
    if m == state["nlp"].friction_margin:
        return state["nlp"]
    if m not in state["friction_nlps"]:
        new = SpeedNLP(model, opts, friction_margin=m)
        state["build_time"] += new.build_time
        state["friction_nlps"][m] = new
    return state["friction_nlps"][m]


def _member(model, opts, points, adv, state, max_refinements):
    """Polish the solution at the target speed, check it on the dense grid, and where an
    active constraint is exceeded between the nodes tighten its node margin by twice the
    excess and solve again, from no margin at each speed, as :func:`gait_opt.optimize_gait`
    does (so that each member solves the same problem as a cold solve).  Returns
    (gait, record); raises GaitOptimizationError when the polish fails."""
    t0 = time.perf_counter()
    v = points[-1].speed
    opts_v = opts.replace(speed=v)
    iterations, nlp = adv.iterations, state["nlp"]
    for attempt in range(1 + max_refinements):
        point = points[-1]
        T, alpha, x0 = nlp.unpack(point)
        alpha_p, x0_p, T_p, hist = polish(model, opts_v, alpha, x0, T)
        gait = Gait(model, opts_v, alpha_p, x0_p, T_p)
        viol = gait.violations()
        fixable = [(FIXED_BY.get(n, n), a) for n, a in viol if FIXED_BY.get(n, n) in MARGINS]
        if not fixable or len(fixable) < len(viol) or attempt == max_refinements:
            break
        margins = dict(point.margins)
        for n, a in fixable:
            margins[n] = margins.get(n, 0.0) + 2 * a + 1e-9
        tighter = _nlp_for(model, opts, state, margins)
        again = tighter.solve_warm(v, point, margins)
        iterations += again.iterations
        if not again.ok:
            break                       # keep this gait and report its violations
        points[-1], nlp = again, tighter
    change = float(np.max(np.abs(np.r_[(alpha_p - alpha).ravel(), x0_p - x0, T_p - T])))
    margins = dict(point.margins)
    gait.solver_stats = dict(
        status=point.status, iterations=iterations, polish_residuals=hist,
        polish_change=change, dense_grid_violations=[list(x) for x in viol],
        family=dict(substeps=adv.substeps, failed_steps=adv.failed, margins=margins,
                    branch=state["branch"]))
    record = MemberRecord(
        speed=float(v), status="ok" if not viol else "violates", iterations=iterations,
        substeps=adv.substeps, failed_steps=adv.failed,
        time=adv.time + time.perf_counter() - t0, T=gait.T, step_length=gait.step_length,
        cost=point.cost, orbit_residual=gait.orbit_residual()["worst"],
        polish_residual=hist[-1], polish_change=change,
        active=active_families(nlp, point), margins=margins,
        violations=[list(x) for x in viol], branch=state["branch"])
    return gait, record


def _events(prev: MemberRecord | None, rec: MemberRecord, jump: dict | None) -> list:
    """Changes from one member to the next: of the active set, of branch."""
    if prev is None:
        return []
    out = [dict(speed=rec.speed, change="branch", constraint=None, detail=_fold_text(jump),
                speed_low=jump["speed_low"], speed_high=jump["speed_high"])
           ] if jump is not None else []
    return out + ([dict(speed=rec.speed, change="active", constraint=c, detail="")
                   for c in rec.active if c not in prev.active]
                  + [dict(speed=rec.speed, change="inactive", constraint=c, detail="")
                     for c in prev.active if c not in rec.active])


def _fold_text(jump: dict) -> str:
    """A jump between branches, in words."""
    rate = "" if jump["rate"] is None else f"; |d theta / d v| was {jump['rate']:.3g} before"
    return (f"the branch followed ends in a fold between {jump['speed_low']:.6g} and "
            f"{jump['speed_high']:.6g} m/s: there the solution jumps by "
            f"{jump['jump']:.3g} (max |Delta theta|, T in s and the Bezier coefficients in "
            f"rad{rate}) to another branch "
            f"(cost {jump['cost_low']:.6g} -> {jump['cost_high']:.6g})")


def _ended(adv: Advance, target: float, last: float, rates: list) -> dict:
    """The family's end: where, why, in words."""
    if adv.jump is not None:
        return dict(speed=float(target), last=float(last), reason="fold",
                    detail=_fold_text(adv.jump), ipopt_status=None, violations=[])
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
    try:
        fam = GaitFamily.load(path, model)
    except ValueError as e:
        raise ValueError(f"path: {e}; remove it, choose another file, or pass "
                         f"resume=False to replace it") from None
    same = (options_record(fam.options) == options_record(opts)
            and len(fam.speeds) == len(speeds)
            and np.allclose(fam.speeds, speeds, rtol=0, atol=SPEED_TOL))
    if not same:
        raise ValueError(f"path: {path} holds a gait family of other options or speeds "
                         f"({len(fam.speeds)} speeds from {fam.speeds[0]:g} to "
                         f"{fam.speeds[-1]:g} m/s); remove it, choose another file, or "
                         f"pass resume=False to replace it")
    return fam


def gait_family(model, speeds, options: GaitOptions | None = None, *, path=None,
                resume: bool = True, across_folds: bool = True, progress=None,
                verbose: bool = False, max_refinements: int = 3) -> GaitFamily:
    """Reference gaits at every speed of a grid, by continuation (module docstring).

    Parameters
    ----------
    model : BipedModel
        The robot.
    speeds : sequence of float
        At least two strictly increasing speeds, m/s (:func:`gait_opt.speed_range`).
    options : GaitOptions, optional
        The problem (default SPEC section 2); its ``speed`` is replaced by each speed,
        its defaults (:meth:`GaitOptions.for_model`) are filled at the slowest.
    path : str or Path, optional
        Save the family there after every member (atomically); with ``resume``,
        continue a partial family found there made for the same robot, options and
        speeds (a finished one is returned as it is).
    resume : bool
        Continue from ``path`` when it holds such a family (False: start afresh and
        replace it).
    across_folds : bool
        Where the branch followed ends in a fold and the solution jumps to another
        branch, continue on that one (an event 'branch'; the members' ``branch``
        numbers say which is which, and :meth:`GaitFamily.gait_at` does not
        interpolate across); False: the family ends there (reason 'fold').
    progress : callable, optional
        Called with one line of text per member.
    verbose : bool
        Print IPOPT's iterations.
    max_refinements : int
        Node-margin refinements per member (as :func:`gait_opt.optimize_gait`).

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
    require_model(model)
    speeds = check_speeds(speeds)
    if options is not None and not isinstance(options, GaitOptions):
        raise ValueError(f"options must be GaitOptions, got {type(options).__name__}")
    base = options or GaitOptions()
    # the defaults filled at the slowest speed (the lower step-length bound follows the
    # speed below the reference speed: one bound for the family, no slower member bound
    # by a faster one's)
    opts = base.replace(speed=float(speeds[0])).for_model(model).replace(speed=base.speed)
    for v in speeds:
        _reachable(opts, v)
    family = _resumable(path, model, opts, speeds) if (path is not None and resume) else None
    if family is not None and family.status != "partial":
        return family
    if family is None:
        family = GaitFamily(status="partial", message="started", robot=model.params.name,
                            speeds=speeds.tolist(), records=[], options=opts)
    return _run(model, opts, speeds, family, path, progress, verbose, max_refinements,
                across_folds)


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


def _run(model, opts, speeds, family, path, progress, verbose, max_refinements,
         across_folds):
    """Continue ``family`` over the speeds it lacks, saving after each member."""
    t_start = time.perf_counter()
    last = family.records[-1] if family.records else None
    nlp = SpeedNLP(model, opts, verbose=verbose)
    state = dict(nlp=nlp, build_time=nlp.build_time, branch=last.branch if last else 0,
                 friction_nlps={})
    points, rates = [], []
    for i in range(len(family.gaits), len(speeds)):
        v = float(speeds[i])
        adv = None
        if not points:
            points, adv = _start(model, opts, state, family, v)
        if adv is None:
            adv = advance(state["nlp"], points, v, v - float(speeds[i - 1]), across_folds)
            rates = [] if adv.jump is not None else rates + adv.rates
            state["branch"] += int(adv.jump is not None and adv.reached)
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
        family.events += _events(family.records[-1] if family.records else None, rec,
                                 adv.jump)
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
    span = (f"{v[0]:g} to {v[-1]:g} m/s" if v.size > 1 else
            f"only {v[0]:g} m/s" if v.size else "no speed")
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
