"""Robustness of a walking controller: the largest perturbation it survives.

The question a user needs answered is not "is max|lambda| < 1" (a local property) but
"from which initial errors does the robot walk, with every contact condition valid, and
converge?".  For one controller design on one gait:

- *directions*: the paper's perturbation (+0.01 rad on every joint, +0.1 rad/s on every
  velocity, §V-C) and seeded sign patterns / random directions of the same per-joint
  size (:func:`biped_casadi.directions`).  The step starts with the swing foot on the
  ground, so many directions put it below the ground at full scale: a start the robot
  cannot be in is not a test of the controller.  A direction is *kept* only if virtual
  constraints walk 10 valid steps from it at full scale (full-order simulation), and the
  result says how many were kept of how many tried.
- *s\\**: the largest scale s of the perturbation (found by bisection on [0, s_max]) at
  which every kept direction walks ``steps`` valid steps (:mod:`biped_casadi.simulation.validity`:
  normal force, friction cone, impact impulse, lift-off, scuffing, torque limit, ...)
  and ends with max(|q_u err|, |dq_u err|) < ``tol``; with the first failure just above
  it and its cause.

Time-varying designs run on their hybrid zero dynamics (:mod:`biped_casadi.simulation.walkers`, exact
for every output gain, batched over directions); virtual constraints in the full-order
simulator.
"""
from __future__ import annotations

import contextlib
import math
import time
from dataclasses import dataclass

import numpy as np

from biped_casadi import (PAPER_REJOIN, SimulationOptions, VirtualConstraintController,
                          directions, require_same_robot, simulate)
from biped_casadi.numerics import as_number
from biped_casadi.control.output_law import SECTION, check_M1
from biped_casadi.simulation.perturbation import PAPER_SIZES
from biped_casadi.results import Result, internal

from ..cluster import dask_client
from ..stability.poincare import poincare_map
from ..sweeps.sweep import gait_from_dict, gait_to_dict
from ..stability.vc_map import vc_eigenvalue
from biped_casadi.simulation.walkers import zero_dynamics_walker

__all__ = ["Design", "RobustnessSettings", "RobustnessResult", "kept_directions",
           "robustness", "start_states", "BatchSStar", "s_star_batch"]


@dataclass(frozen=True)
class Design:
    """A time-varying controller design: the output matrix M1 and the rejoin time of v_c.

    The rejoin time is when the correction v_c rejoins the reference, as a fraction of
    T (the paper: 1/2; at most the Poincaré section, 0.75).  The output gains do not
    matter for walking (the closed loop is its zero dynamics) and are not part of a
    design.

    Parameters
    ----------
    M1 : tuple of float
        One number per actuated joint (a sequence is converted to a tuple of floats).
    rejoin : float
        Rejoin time of v_c, fraction of T, in (0, 0.75].
    """

    M1: tuple
    rejoin: float = PAPER_REJOIN

    def __post_init__(self):
        M1 = np.atleast_1d(np.asarray(self.M1, dtype=float))
        object.__setattr__(self, "M1", tuple(check_M1(M1, M1.size).tolist()))
        r = as_number(self.rejoin, "rejoin", positive=True)
        if r > SECTION:
            raise ValueError(f"rejoin must be in (0, {SECTION}], got {self.rejoin!r}")
        object.__setattr__(self, "rejoin", r)

    def to_dict(self) -> dict:
        """The design in plain JSON types.

        Returns
        -------
        dict
            ``controller`` 'tv', ``M1`` as a list of float and ``rejoin`` (fraction
            of T).
        """
        return dict(controller="tv", M1=list(self.M1), rejoin=self.rejoin)


@dataclass(frozen=True)
class RobustnessSettings:
    """How robustness is measured.

    Parameters
    ----------
    directions : int
        Kept directions (the paper's first, then seeded ones).
    seed : int
        Seed of the candidate directions.
    max_candidates : int
        Candidates tried to keep ``directions`` of them.
    steps : int
        Steps every run must walk.
    tol : float
        ``max(|q_u err|, |dq_u err|)`` at the last step must be below this (rad and
        rad/s).
    s_max : float
        The largest scale tried.
    rounds : int
        Bisection rounds (resolution ``s_max / 2^(rounds - 1)``).
    mu : float
        Friction coefficient (stance foot and impact impulse).
    torque_limit : float, optional
        Bound on ``|u_i|``, N m (default the robot's).
    rk4_steps : int
        RK4 steps per T of the zero-dynamics walker.
    """

    directions: int = 16
    seed: int = 2024
    max_candidates: int = 200
    steps: int = 10
    tol: float = 1e-3
    s_max: float = 2.0
    rounds: int = 8
    mu: float = 0.6
    torque_limit: float | None = None
    rk4_steps: int = 400

    def simulation_options(self, jit: bool = False) -> SimulationOptions:
        """The simulation options of the runs: ``steps``, ``mu`` and ``torque_limit``.

        Parameters
        ----------
        jit : bool
            Compile the simulator's functions to C.

        Returns
        -------
        SimulationOptions
            With the steps to walk, the friction coefficient and the torque limit of
            these settings, the other options at their defaults.
        """
        return SimulationOptions(steps=self.steps, mu=self.mu, torque_limit=self.torque_limit,
                                 jit=jit)


@dataclass
class RobustnessResult(Result):
    """Robustness of one design (see the module docstring).

    ``status`` is always 'done' (``success``).  The kept directions are left out of
    ``to_dict()``.

    Parameters
    ----------
    controller : str
        'tv' (time-varying design) or 'vc' (virtual constraints).
    design : dict
        :meth:`Design.to_dict` of the time-varying design, or ``{"controller": "vc"}``.
    s_star : float
        The largest scale at which every kept direction walks and converges (0 when no
        scale tried passed; ``s_max`` when every direction passes there).
    s_fail : float
        The scale just above ``s_star`` (bisection) where ``failure`` happened; inf
        when every direction passes at ``s_max``.
    failure : dict
        The failure at ``s_fail``: direction index, status ('not_converged' or a
        validity status), step and final error; empty when there is none.
    steps_to_converge : float
        At s*, the worst over the kept directions of the steps until the error stays
        below ``tol``; NaN when no scale passed.
    paper : dict
        The run from the paper's perturbation (direction 0 at s = 1): status, steps to
        converge, validity margins; empty when direction 0 is not the paper's.
    max_abs : float
        max ``|lambda|`` of the linearised restricted Poincaré map of the design (for
        virtual constraints: ``|eigenvalue|``).
    directions_kept : int
        Directions used (virtual constraints walk from them at full scale).
    directions_tried : int
        Candidate directions tried to keep them.
    directions_rejected : dict
        Status -> number of candidates rejected with it.
    settings : dict
        The :class:`RobustnessSettings` fields.
    elapsed : float
        Wall time, s.
    runs : int
        Runs (walks from one start state) made by the bisection and the paper's run.
    status : str
        'done'.
    message : str
        s* in words, with the failure just above it.
    kept : numpy.ndarray
        (k, 2 nq) the kept directions (left out of ``to_dict()``).
    """

    controller: str
    design: dict
    s_star: float
    s_fail: float
    failure: dict
    steps_to_converge: float
    paper: dict
    max_abs: float
    directions_kept: int
    directions_tried: int
    directions_rejected: dict
    settings: dict
    elapsed: float
    runs: int
    status: str = "done"
    message: str = ""
    kept: np.ndarray = internal(default=None)

    SUCCESS = ("done",)


def start_states(gait, dirs, scales, sizes=PAPER_SIZES):
    """Start states (q0, dq0) of perturbation directions at given scales.

    The perturbation of a direction d at scale s adds ``sizes[0] * s * d[:nq]`` (rad) to
    the reference configuration at the start of the step (tau = 0) and
    ``sizes[1] * s * d[nq:]`` (rad/s) to its velocities.

    Parameters
    ----------
    gait : Reference
        The reference step.
    dirs : array_like
        (n, 2 nq) directions (one direction (2 nq,) is a batch of one).
    scales : float or array_like
        (n,) scales, broadcast along the directions.
    sizes : tuple of float
        Per-joint perturbation size at scale 1: rad for the angles, rad/s for the
        velocities (default the paper's 0.01 rad and 0.1 rad/s).

    Returns
    -------
    q0, dq0 : numpy.ndarray
        (n, nq) start configurations (rad) and velocities (rad/s).
    """
    dirs = np.atleast_2d(np.asarray(dirs, float))
    nq = gait.model.nq
    s = np.broadcast_to(np.asarray(scales, float), (len(dirs),))[:, None]
    return (gait.q(0.0)[None, :] + sizes[0] * s * dirs[:, :nq],
            gait.dq(0.0)[None, :] + sizes[1] * s * dirs[:, nq:])


def _vc_run(model, gait, options, d, s):
    q0, dq0 = start_states(gait, d[None], s)
    return simulate(VirtualConstraintController(model, gait), q0[0], dq0[0], options)


def kept_directions(model, gait, settings: RobustnessSettings | None = None, progress=None):
    """The directions from which virtual constraints walk at full scale.

    Parameters
    ----------
    model : BipedModel
        The robot.
    gait : Reference
        The reference step, made for ``model``.
    settings : RobustnessSettings, optional
        Candidates, seed, steps and validity thresholds (default: all defaults).
    progress : callable, optional
        Called with a line of text per candidate tried.

    Returns
    -------
    tuple
        (kept directions (k, 2 nq), candidates tried, {status: count} of the rejected).
    """
    st = settings or RobustnessSettings()
    opts = st.simulation_options(jit=True)
    cand = directions(st.max_candidates, model.nq, st.seed)
    kept, rejected = [], {}
    tried = 0
    for d in cand:
        tried += 1
        r = _vc_run(model, gait, opts, d, 1.0)
        if r.success:
            kept.append(d)
        else:
            rejected[r.status] = rejected.get(r.status, 0) + 1
        if progress is not None:
            progress(f"direction {tried}: virtual constraints {r.status} "
                     f"({len(kept)} kept of {st.directions})")
        if len(kept) == st.directions:
            break
    return np.array(kept).reshape(-1, 2 * model.nq), tried, rejected


# ------------------------------------------------------------------ runners
class _TVRunner:
    """Batches of runs of one time-varying design on the zero-dynamics walker."""

    def __init__(self, model, gait, design: Design, st: RobustnessSettings):
        self.walker = zero_dynamics_walker(model, gait, st.simulation_options(),
                                           st.rk4_steps, jit=True)
        self.gait, self.design, self.st = gait, design, st
        self.runs = 0

    def run(self, dirs, s):
        q0, dq0 = start_states(self.gait, dirs, s)
        B = self.walker.walk(q0, dq0, np.array(self.design.M1), self.design.rejoin,
                             steps=self.st.steps)
        self.runs += len(dirs)
        err = B.final_error
        out = []
        for i in range(len(dirs)):
            status = str(B.run_status[i])
            if status == "ok" and not err[i] < self.st.tol:
                status = "not_converged"
            out.append(dict(status=status, step=int(B.fail_step[i]),
                            error=float(err[i]) if np.isfinite(err[i]) else None,
                            steps_to_converge=float(B.steps_to_converge(self.st.tol)[i]),
                            peak_torque=float(B.peak_torque[i]),
                            min_normal_force=float(B.min_normal_force[i]),
                            max_friction_ratio=float(B.max_friction_ratio[i]),
                            max_impulse_ratio=float(B.max_impulse_ratio[i])))
        return out


class _VCRunner:
    """Full-order runs of virtual constraints fitted to the gait."""

    def __init__(self, model, gait, st: RobustnessSettings):
        self.model, self.gait, self.st = model, gait, st
        self.options = st.simulation_options(jit=True)
        self.runs = 0

    def run(self, dirs, s):
        out = []
        for d in dirs:
            r = _vc_run(self.model, self.gait, self.options, d, s)
            self.runs += 1
            err = (max(abs(r.qu_errors[-1]), abs(r.dqu_errors[-1]))
                   if r.success and r.steps else math.inf)
            status = r.status if not (r.success and not err < self.st.tol) else "not_converged"
            out.append(dict(status=status,
                            step=r.failed_step if r.failed_step is not None else len(r.steps),
                            error=err if math.isfinite(err) else None,
                            steps_to_converge=float(r.steps_to_converge(self.st.tol) or np.nan),
                            peak_torque=r.peak_torque, min_normal_force=r.min_normal_force,
                            max_friction_ratio=r.max_friction_ratio,
                            max_impulse_ratio=r.max_impulse_ratio))
        return out


def _all_pass(outcomes) -> bool:
    return all(o["status"] == "ok" for o in outcomes)


def _first_failure(outcomes) -> dict:
    """The failing direction to report: a validity failure before non-convergence,
    then the earliest step."""
    bad = [(i, o) for i, o in enumerate(outcomes) if o["status"] != "ok"]
    i, o = min(bad, key=lambda io: (io[1]["status"] == "not_converged", io[1]["step"]))
    return dict(direction=i, status=o["status"], step=o["step"], error=o["error"])


def _bisect(runner, dirs, st: RobustnessSettings):
    """(s*, s_fail, failure at s_fail, outcomes at s*)."""
    hi_out = runner.run(dirs, st.s_max)
    if _all_pass(hi_out):
        return st.s_max, math.inf, {}, hi_out
    lo, hi, fail, lo_out = 0.0, st.s_max, _first_failure(hi_out), None
    for _ in range(st.rounds - 1):
        mid = 0.5 * (lo + hi)
        out = runner.run(dirs, mid)
        if _all_pass(out):
            lo, lo_out = mid, out
        else:
            hi, fail = mid, _first_failure(out)
    return lo, hi, fail, lo_out


def robustness(model, gait, design: Design | None = None,
               settings: RobustnessSettings | None = None, kept=None,
               progress=None) -> RobustnessResult:
    """s* of a time-varying design (``design``) or of virtual constraints (``None``).

    Parameters
    ----------
    model : BipedModel
        The robot.
    gait : Reference
        The reference step, made for ``model``.
    design : Design, optional
        The time-varying design; None measures virtual constraints fitted to the gait.
    settings : RobustnessSettings, optional
        How robustness is measured (default: all defaults).
    kept : tuple, optional
        (directions, tried, rejected) from :func:`kept_directions`, to reuse.
    progress : callable, optional
        Called with one line of text per stage.

    Returns
    -------
    RobustnessResult
    """
    require_same_robot(model, gait)
    st = settings or RobustnessSettings()
    t0 = time.perf_counter()
    if kept is None:
        kept = kept_directions(model, gait, st, progress)
    dirs, tried, rejected = kept
    if len(dirs) == 0:
        raise ValueError("no perturbation direction is walkable by virtual constraints on "
                         "this gait at full scale: robustness is undefined (try more "
                         "candidates or another gait)")
    if design is None:
        runner, name = _VCRunner(model, gait, st), "virtual constraints"
        ev = vc_eigenvalue(model, gait)
        max_abs, design_dict = abs(ev.eigenvalue), dict(controller="vc")
    else:
        if len(design.M1) != model.nu:
            raise ValueError(f"design: M1 must have {model.nu} components, got {len(design.M1)}")
        runner, name = _TVRunner(model, gait, design, st), f"M1 = {list(design.M1)}"
        pm = poincare_map(model, gait, rejoin=design.rejoin)
        max_abs, design_dict = pm.analyse(np.array(design.M1)).max_abs, design.to_dict()
    if progress is not None:
        progress(f"s* of {name}: bisection on [0, {st.s_max:g}] over {len(dirs)} directions")
    s_star, s_fail, failure, at_star = _bisect(runner, dirs, st)
    paper = runner.run(dirs[:1], 1.0)[0] if np.all(dirs[0] == 1) else {}
    worst = (max(o["steps_to_converge"] for o in at_star) if at_star else math.nan)
    msg = (f"{name}: s* = {s_star:.4g} " + (
        f"(all {len(dirs)} directions walk {st.steps} valid steps and converge below "
        f"{st.tol:g})" if s_star > 0 else "(no scale tried passed)") + (
               f"; at s = {s_fail:.4g} direction {failure['direction']} fails: "
               f"{failure['status']} in step {failure['step']}" if failure else ""))
    return RobustnessResult(
        controller="tv" if design is not None else "vc", design=design_dict,
        s_star=s_star, s_fail=s_fail, failure=failure, steps_to_converge=worst,
        paper=paper, max_abs=max_abs, directions_kept=len(dirs), directions_tried=tried,
        directions_rejected=dict(rejected), settings=st.__dict__.copy(),
        elapsed=time.perf_counter() - t0, runs=runner.runs, message=msg, kept=dirs)


# ------------------------------------------------------- many designs at once
@dataclass
class BatchSStar:
    """s* of many time-varying designs (row i = design i).

    Parameters
    ----------
    s_star : numpy.ndarray
        (n,) the largest scale passed by every direction.
    s_fail : numpy.ndarray
        (n,) the scale just above it where a direction failed; inf when all pass at
        ``s_max``.
    cause : list of str
        The status of the first failure at ``s_fail`` (with its step), '' where none.
    pass_fraction : numpy.ndarray
        (n,) fraction of directions that pass at ``s_fail`` (a tie-breaker inside one
        bisection cell).
    scenario_steps : int
        The scenario-steps walked.
    """
    s_star: np.ndarray
    s_fail: np.ndarray
    cause: list
    pass_fraction: np.ndarray
    scenario_steps: int


def _verdicts(B, nd, nk, tol):
    """Per design: all directions pass, the fraction that pass, the cause to report."""
    err = B.final_error
    st = np.where((B.run_status == "ok") & ~(err < tol), "not_converged", B.run_status)
    st = st.reshape(nd, nk)
    step = B.fail_step.reshape(nd, nk)
    ok = st == "ok"
    causes = []
    for i in range(nd):
        bad = np.flatnonzero(~ok[i])
        if not bad.size:
            causes.append("")
            continue
        j = bad[np.lexsort((step[i, bad], st[i, bad] == "not_converged"))[0]]
        causes.append(f"{st[i, j]} in step {step[i, j]}" if st[i, j] != "not_converged"
                      else "not_converged")
    return ok.all(axis=1), ok.mean(axis=1), causes


def _walk_task(gait_dict, options, rk4_steps, q0, dq0, M1s, rejoin, steps):
    """One batch walked on a Dask worker (the walker built once per worker process)."""
    gait = gait_from_dict(gait_dict)
    walker = zero_dynamics_walker(gait.model, gait, options, rk4_steps, jit=True)
    return walker.walk(q0, dq0, M1s, rejoin, steps=steps)


def s_star_batch(walker, gait, designs, dirs, settings: RobustnessSettings,
                 rounds: int | None = None, chunk: int = 64, scheduler=None) -> BatchSStar:
    """s* of many time-varying designs by one bisection run in batches.

    Every round walks (designs still bracketing) x (directions) scenarios together.

    Parameters
    ----------
    walker : ZeroDynamicsWalker
        The walker of ``gait`` (its options and RK4 steps are used on Dask workers).
    gait : Reference
        The reference step.
    designs : list of Design
        The time-varying designs.
    dirs : array
        Kept directions (k, 2 nq).
    settings : RobustnessSettings
        Steps, tolerance, ``s_max`` and default bisection rounds.
    rounds : int, optional
        Bisection rounds (default ``settings.rounds``).
    chunk : int
        Designs per walker batch.
    scheduler : str or dask.distributed.Client, optional
        Walk the batches of each round on a Dask cluster's workers (each builds the
        walker once) instead of in this process.

    Returns
    -------
    BatchSStar
    """
    st = settings
    rounds = st.rounds if rounds is None else rounds
    nd, nk = len(designs), len(dirs)
    M1 = np.array([d.M1 for d in designs], float)
    rj = np.array([d.rejoin for d in designs], float)
    lo, hi = np.zeros(nd), np.full(nd, st.s_max)
    cause, frac = [""] * nd, np.ones(nd)
    used = 0

    def batches(idx, scales):
        for a in range(0, idx.size, chunk):
            part = idx[a:a + chunk]
            q0, dq0 = start_states(gait, np.tile(dirs, (part.size, 1)),
                                   np.repeat(scales[a:a + chunk], nk))
            yield part, (q0, dq0, np.repeat(M1[part], nk, axis=0), np.repeat(rj[part], nk))

    def walked(idx, scales):
        if client is None:
            for part, args in batches(idx, scales):
                yield part, walker.walk(*args, steps=st.steps)
            return
        futs = [(part, client.submit(_walk_task, gdict, walker.options, walker.rk4_steps,
                                     *args, st.steps, pure=False))
                for part, args in batches(idx, scales)]
        for part, f in futs:
            yield part, f.result()

    def evaluate(idx, scales):
        nonlocal used
        ok_all, fr_all, c_all = np.zeros(idx.size, bool), np.zeros(idx.size), []
        a = 0
        for part, B in walked(idx, scales):
            used += B.scenario_steps
            ok, fr, c = _verdicts(B, part.size, nk, st.tol)
            ok_all[a:a + part.size], fr_all[a:a + part.size] = ok, fr
            c_all += c
            a += part.size
        return ok_all, fr_all, c_all

    gdict = gait_to_dict(gait) if scheduler is not None else None
    with (dask_client(scheduler) if scheduler is not None else contextlib.nullcontext()) \
            as client:
        return _bisect_many(evaluate, nd, lo, hi, cause, frac, rounds, st,
                            lambda: used)


def _bisect_many(evaluate, nd, lo, hi, cause, frac, rounds, st, used):
    """The rounds of :func:`s_star_batch`'s bisection."""
    idx = np.arange(nd)
    ok, fr, c = evaluate(idx, hi)
    lo[ok] = st.s_max
    hi[ok] = math.inf
    for i in np.flatnonzero(~ok):
        cause[i], frac[i] = c[i], fr[i]
    active = ~ok
    for _ in range(rounds - 1):
        idx = np.flatnonzero(active)
        if not idx.size:
            break
        mid = 0.5 * (lo[idx] + hi[idx])
        ok, fr, c = evaluate(idx, mid)
        lo[idx[ok]] = mid[ok]
        hi[idx[~ok]] = mid[~ok]
        for k in np.flatnonzero(~ok):
            cause[idx[k]], frac[idx[k]] = c[k], fr[k]
    return BatchSStar(lo, hi, cause, frac, used())
