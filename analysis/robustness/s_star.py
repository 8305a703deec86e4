"""Robustness of a walking controller: the largest perturbation it survives.

The question a user needs answered is not "is max|lambda| < 1" (a local property) but
"from which initial errors does the robot walk, with every contact condition valid, and
converge?".  For one controller design on one gait:

- *directions*: the paper's perturbation (+0.01 rad on every joint, +0.1 rad/s on every
  velocity, §V-C) and seeded sign patterns / random directions of the same per-joint
  size (:func:`biped_casadi.directions`).  The step starts with the swing foot on the
  ground, so many directions put it below the ground at full scale: a start the robot
  cannot be in is not a test of the controller.  A direction is *kept* only if virtual
  constraints walk 10 valid steps from it at full scale, and the
  result says how many were kept of how many tried.
- *s\\**: the largest scale s of the perturbation (found by bisection on [0, s_max]) at
  which every kept direction walks ``steps`` valid steps (:mod:`biped_casadi.simulation.validity`:
  normal force, friction cone, impact impulse, lift-off, scuffing, torque limit, ...)
  and ends with max(|q_u err|, |dq_u err|) < ``tol``; with the first failure just above
  it and its cause.

Both controllers run on their hybrid zero dynamics, batched over directions: time-varying
designs on :mod:`biped_casadi.simulation.tv_walker` (exact for every output gain),
virtual constraints on :mod:`biped_casadi.simulation.vc_walker` (exact with their
phase-based correction).  Both walkers check every validity condition of the full-order
simulator at their nodes, and as it does the swing foot, the stance force, the friction
cone and the torques between them too (:mod:`biped_casadi.simulation.margins`);
``tests/test_robust.py`` compares their verdicts with it.
"""
from __future__ import annotations

import contextlib
import math
import time
from dataclasses import dataclass

import numpy as np

from biped_casadi import Design, SimulationOptions, directions, require_same_robot
from biped_casadi.control.output_law import require_regular
from biped_casadi.control.reference import require_reference
from biped_casadi.numerics import as_count, as_number
from biped_casadi.results import Result, internal
from biped_casadi.simulation import (WalkBatch, start_states, virtual_constraint_walker,
                                     zero_dynamics_walker)
from biped_casadi.simulation.outcome import NOT_CONVERGED, failure_text
from biped_casadi.simulation.perturbation import PAPER_SIZES

from ..tasks import Engine, resolve_scheduler, task
from ..stability.poincare import poincare_map
from ..stability.vc_map import vc_eigenvalue

__all__ = ["Design", "RobustnessSettings", "RobustnessResult", "KeptDirections", "decay_steps",
           "steps_short", "kept_directions", "robustness", "BatchSStar", "s_star_batch",
           "bisect_scale", "walk_batch"]


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

    def __post_init__(self):
        for name, low in (("directions", 1), ("seed", 0), ("max_candidates", 1), ("steps", 1),
                          ("rounds", 1), ("rk4_steps", 8)):
            object.__setattr__(self, name, as_count(getattr(self, name), name, low))
        if self.rk4_steps % 8:
            raise ValueError(f"rk4_steps must be a positive multiple of 8, got {self.rk4_steps}")
        for name in ("tol", "s_max", "mu") + (("torque_limit",) if self.torque_limit is not None
                                              else ()):
            object.__setattr__(self, name, as_number(getattr(self, name), name, positive=True))

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


def decay_steps(eigenvalue: float, settings: RobustnessSettings | None = None) -> int:
    """Steps for s* on a slowly converging gait, from the virtual constraints' rate.

    Enough for the largest perturbation tried to decay below the tolerance at that rate.

    With ``tol`` 1e-3 within 10 steps, a gait whose virtual-constraint eigenvalue is near
    0.85 has s* near 0 for every design (0.85^10 = 0.2: the paper's perturbation, 0.1
    rad/s, cannot fall below 1e-3), so s* then measures the convergence rate, not the
    perturbations survived.  This count N is the least with
    ``s_max * 0.1 * |eigenvalue|^N <= tol``, and at least ``settings.steps``: RABBIT's
    default gait (0.54) keeps 10.

    Parameters
    ----------
    eigenvalue : float
        The virtual constraints' eigenvalue on the gait (:func:`vc_eigenvalue`).
    settings : RobustnessSettings, optional
        ``tol``, ``s_max`` and the least count ``steps`` (default: the defaults).

    Returns
    -------
    int

    Raises
    ------
    ValueError
        An eigenvalue not inside the unit circle (no decay: no count is enough).
    """
    st = _settings(settings)
    lam = abs(as_number(eigenvalue, "eigenvalue"))
    if not lam < 1:
        raise ValueError(f"eigenvalue: virtual constraints must be stable for a decay, got "
                         f"|{eigenvalue!r}| >= 1")
    start = st.s_max * max(PAPER_SIZES)
    if lam == 0 or start <= st.tol:
        return st.steps
    return max(st.steps, math.ceil(math.log(st.tol / start) / math.log(lam)))


def steps_short(eigenvalue: float, settings: RobustnessSettings | None = None) -> int | None:
    """The steps the virtual constraints' rate needs when the settings walk fewer.

    Then s* over ``settings.steps`` measures how fast a design converges, for virtual
    constraints too (often 0), not the perturbations survived (:func:`decay_steps`).

    Parameters
    ----------
    eigenvalue : float
        The virtual constraints' eigenvalue on the gait.
    settings : RobustnessSettings, optional
        The protocol (default: the defaults).

    Returns
    -------
    int or None
        :func:`decay_steps` when above ``settings.steps``; None when not, or when the
        eigenvalue is not inside the unit circle (no count is enough).
    """
    try:
        n = decay_steps(eigenvalue, settings)
    except ValueError:
        return None
    return n if n > _settings(settings).steps else None


@dataclass
class RobustnessResult(Result):
    """Robustness of one design (see the module docstring).

    ``success`` means s* was measured; ``status`` is 'done'.  The kept directions are left
    out of ``to_dict()``.

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
        validity status), step (0-based, ``WalkOutcome.fail_step``; the message says
        step + 1) and final error; empty when there is none.
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


@dataclass
class KeptDirections(Result):
    """The perturbation directions from which virtual constraints walk at full scale.

    ``success`` means the candidates were tried; ``status`` is 'done'.

    Parameters
    ----------
    directions : numpy.ndarray
        (k, 2 nq) the kept directions (the paper's first when it is kept).
    tried : int
        Candidates tried to keep them.
    rejected : dict
        Status -> number of candidates rejected with it.
    status : str
        'done'.
    message : str
        How many were kept of how many tried.
    """

    directions: np.ndarray
    tried: int
    rejected: dict
    status: str = "done"
    message: str = ""

    SUCCESS = ("done",)

    def __len__(self) -> int:
        return len(self.directions)


#: RK4 nodes per step of the virtual constraints' walker in the s* protocol
VC_NODES = 200


def _vc_runs(gait, options, dirs, scale) -> WalkBatch:
    """Runs of virtual constraints fitted to the gait, one per direction, batched on their
    hybrid zero dynamics (:meth:`~biped_casadi.simulation.VirtualConstraintWalker.walk_from_states`:
    exact for the controller with its phase-based correction, which puts the closed
    loop on the step's corrected surface from any start)."""
    q0, dq0 = start_states(gait, dirs, scale)
    walker = virtual_constraint_walker(gait, options, VC_NODES, jit=True)
    return walker.walk_from_states(q0, dq0, steps=options.steps)


_KEEP_BATCH = 32          # candidate directions walked at once


@task
def kept_directions(gait, settings: RobustnessSettings | None = None,
                    progress=None) -> KeptDirections:
    """The directions from which virtual constraints walk at full scale.

    Parameters
    ----------
    gait : Reference
        The reference step, made for ``model``.
    settings : RobustnessSettings, optional
        Candidates, seed, steps and validity thresholds (default: all defaults).
    progress : callable, optional
        Called with a line of text per candidate tried.

    Returns
    -------
    KeptDirections
    """
    model = require_reference(gait).model
    st = _settings(settings)
    opts = st.simulation_options()
    cand = directions(st.max_candidates, model.nq, st.seed)
    kept, rejected = [], {}
    tried = 0
    for start in range(0, len(cand), _KEEP_BATCH):      # in order, a batch at a time
        status = _vc_runs(gait, opts, cand[start:start + _KEEP_BATCH], 1.0).status
        for d, s in zip(cand[start:start + _KEEP_BATCH], status):
            tried += 1
            s = str(s)
            if s == "ok":
                kept.append(d)
            else:
                rejected[s] = rejected.get(s, 0) + 1
            if progress is not None:
                progress(f"direction {tried}: virtual constraints {s} "
                         f"({len(kept)} kept of {st.directions})")
            if len(kept) == st.directions:
                break
        if len(kept) == st.directions:
            break
    return KeptDirections(np.array(kept).reshape(-1, 2 * model.nq), tried, rejected,
                          message=f"{len(kept)} of {tried} candidate directions kept")


# ---------------------------------------------------------------- verdicts
def _settings(settings) -> RobustnessSettings:
    """``settings`` or the defaults; anything but a RobustnessSettings named."""
    if settings is None:
        return RobustnessSettings()
    if not isinstance(settings, RobustnessSettings):
        raise ValueError(f"settings must be a RobustnessSettings, got {type(settings).__name__}")
    return settings


def _failure(batch: WalkBatch, tol: float):
    """The failing run to report of a design's runs (one per direction), or None: a
    validity failure before non-convergence, then the earliest step, then the first."""
    v = batch.verdict(tol)
    bad = np.flatnonzero(v != "ok")
    if not bad.size:
        return None
    return int(bad[np.lexsort((batch.fail_step[bad], v[bad] == NOT_CONVERGED))[0]])


def _run_summary(batch: WalkBatch, i: int, tol: float) -> dict:
    """Run i of a batch as the robustness result reports it."""
    err = float(batch.final_error[i])
    return dict(status=str(batch.verdict(tol)[i]), step=int(batch.fail_step[i]),
                error=err if np.isfinite(err) else None,
                steps_to_converge=float(batch.steps_to_converge(tol)[i]),
                peak_torque=float(batch.peak_torque[i]),
                min_normal_force=float(batch.min_normal_force[i]),
                max_friction_ratio=float(batch.max_friction_ratio[i]),
                max_impulse_ratio=float(batch.max_impulse_ratio[i]))


def bisect_scale(evaluate, n: int, s_max: float, rounds: int):
    """The largest scale in [0, s_max] that each of n designs passes, by bisection.

    Round 1 tries ``s_max``; every further round halves the bracket of the designs still
    open, all of them in one call.

    Parameters
    ----------
    evaluate : callable
        ``evaluate(idx, scales) -> (passed, info)``: for the designs ``idx`` at their
        ``scales``, a boolean array and one object per design (kept for the result).
    n : int
        Designs.
    s_max : float
        The largest scale.
    rounds : int
        Calls of ``evaluate`` at most (resolution ``s_max / 2^(rounds - 1)``).

    Returns
    -------
    tuple
        (s_star (n,), s_fail (n,), info at s_star, info at s_fail): s_star 0 when no
        scale passed; s_fail inf when ``s_max`` passed; infos None where none.
    """
    lo, hi = np.zeros(n), np.full(n, float(s_max))
    at_lo, at_hi = [None] * n, [None] * n
    idx, scales = np.arange(n), hi.copy()
    for r in range(rounds):
        if not idx.size:
            break
        ok, info = evaluate(idx, scales)
        for j, i in enumerate(idx):
            if ok[j]:
                lo[i], at_lo[i] = scales[j], info[j]
                if r == 0:
                    hi[i] = math.inf
            else:
                hi[i], at_hi[i] = scales[j], info[j]
        idx = idx[~np.asarray(ok, bool)] if r == 0 else np.flatnonzero(np.isfinite(hi))
        scales = 0.5 * (lo[idx] + hi[idx])
    return lo, hi, at_lo, at_hi


# ------------------------------------------------------------------ one design
def _runner(gait, design, st: RobustnessSettings):
    """``run(dirs, s) -> WalkBatch``: the design's (or virtual constraints') runs."""
    if design is None:
        opts = st.simulation_options()
        return lambda dirs, s: _vc_runs(gait, opts, dirs, s)
    walker = zero_dynamics_walker(gait, st.simulation_options(), st.rk4_steps, jit=True)

    def run(dirs, s):
        q0, dq0 = start_states(gait, dirs, s)
        return walker.walk(q0, dq0, np.array(design.M1), design.rejoin, steps=st.steps)
    return run


@task
def robustness(design: Design, settings: RobustnessSettings | None = None, kept=None,
               progress=None) -> RobustnessResult:
    """s* of a design: a time-varying one, or virtual constraints.

    ``robustness(Design.vc(gait))`` measures virtual constraints on the gait,
    ``robustness(Design.tv(gait, M1, rejoin))`` a time-varying design on it.

    Parameters
    ----------
    design : Design
        The design and its gait (:class:`biped_casadi.Design`).
    settings : RobustnessSettings, optional
        How robustness is measured (default: all defaults).
    kept : KeptDirections, optional
        From :func:`kept_directions`, to reuse.
    progress : callable, optional
        Called with one line of text per stage.

    Returns
    -------
    RobustnessResult

    Raises
    ------
    ValueError
        When the design is a time-varying one singular on its step (eq. 24): no run of
        it is a walk, so s* would say nothing about the design.
    """
    design = Design.require(design)
    if design.M1 is not None:
        require_regular(design.controller_for(), design.M1)
    return _robustness(design, settings, kept, progress)


def _robustness(design: Design, settings, kept, progress) -> RobustnessResult:
    """:func:`robustness` without the singularity check: the co-design measures every
    candidate its solver returns, a singular one too (its s* is 0)."""
    gait = design.gait
    model = gait.model
    require_same_robot(model, gait)
    st = _settings(settings)
    t0 = time.perf_counter()
    if kept is None:
        kept = kept_directions(gait, st, progress)
    elif not isinstance(kept, KeptDirections):
        raise ValueError(f"kept must be the KeptDirections of kept_directions(gait), got "
                         f"{type(kept).__name__}")
    dirs = kept.directions
    if len(dirs) == 0:
        raise ValueError("no perturbation direction is walkable by virtual constraints on "
                         "this gait at full scale: robustness is undefined (try more "
                         "candidates or another gait)")
    if design.M1 is None:
        name = "virtual constraints"
        max_abs, design_dict = abs(vc_eigenvalue(gait).eigenvalue), dict(controller="vc")
    else:
        if len(design.M1) != model.nu:
            raise ValueError(f"design: M1 must have {model.nu} components, got {len(design.M1)}")
        name = f"M1 = {list(design.M1)}"
        pm = poincare_map(gait, rejoin=design.rejoin)
        max_abs = pm.analyse(np.array(design.M1)).max_abs
        design_dict = dict(controller="tv", M1=list(design.M1), rejoin=design.rejoin)
    run = _runner(gait, None if design.M1 is None else design, st)
    runs = 0
    if progress is not None:
        progress(f"s* of {name}: bisection on [0, {st.s_max:g}] over {len(dirs)} directions")

    def evaluate(idx, scales):
        nonlocal runs
        b = run(dirs, scales[0])
        runs += len(dirs)
        return np.array([_failure(b, st.tol) is None]), [b]

    lo, hi, at_lo, at_hi = bisect_scale(evaluate, 1, st.s_max, st.rounds)
    s_star, s_fail = float(lo[0]), float(hi[0])
    failure = {}
    if at_hi[0] is not None:
        j = _failure(at_hi[0], st.tol)
        s = _run_summary(at_hi[0], j, st.tol)
        failure = dict(direction=j, status=s["status"], step=s["step"], error=s["error"])
    paper = {}
    if np.all(dirs[0] == 1):
        paper = _run_summary(run(dirs[:1], 1.0), 0, st.tol)
        runs += 1
    worst = (float(np.max(at_lo[0].steps_to_converge(st.tol))) if at_lo[0] is not None
             else math.nan)
    msg = (f"{name}: s* = {s_star:.4g} " + (
        f"(all {len(dirs)} directions walk {st.steps} valid steps and converge below "
        f"{st.tol:g})" if s_star > 0 else "(no scale tried passed)") + (
               f"; at s = {s_fail:.4g} direction {failure['direction']} fails: "
               + failure_text(failure['status'], failure['step']) if failure else ""))
    return RobustnessResult(
        controller=design.controller, design=design_dict,
        s_star=s_star, s_fail=s_fail, failure=failure, steps_to_converge=worst,
        paper=paper, max_abs=max_abs, directions_kept=len(dirs), directions_tried=kept.tried,
        directions_rejected=dict(kept.rejected), settings=st.__dict__.copy(),
        elapsed=time.perf_counter() - t0, runs=runs, message=msg, kept=dirs)


# ------------------------------------------------------- many designs at once
@dataclass
class BatchSStar(Result):
    """s* of many time-varying designs (row i = design i).

    ``success`` means every design was measured; ``status`` is 'done'.

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
    status : str
        'done'.
    message : str
        The best s* in words.
    """
    s_star: np.ndarray
    s_fail: np.ndarray
    cause: list
    pass_fraction: np.ndarray
    scenario_steps: int
    status: str = "done"
    message: str = ""

    SUCCESS = ("done",)


def _cause(batch: WalkBatch, tol: float) -> str:
    j = _failure(batch, tol)
    if j is None:
        return ""
    v = str(batch.verdict(tol)[j])
    return v if v == NOT_CONVERGED else failure_text(v, int(batch.fail_step[j]))


@task
def walk_batch(gait, options: SimulationOptions, rk4_steps: int, q0, dq0, M1s, rejoin,
               steps: int) -> WalkBatch:
    """One batch of s*'s bisection walked on the zero dynamics (a task; the walker is
    built once per process).

    Parameters
    ----------
    gait : Gait
        The reference.
    options : SimulationOptions
        The walker's validity thresholds.
    rk4_steps : int
        RK4 steps per T.
    q0, dq0 : numpy.ndarray
        (n, nq) start states.
    M1s : numpy.ndarray
        (n, nu) outputs.
    rejoin : numpy.ndarray
        (n,) rejoin times, fractions of T.
    steps : int
        Steps to walk.

    Returns
    -------
    WalkBatch
    """
    walker = zero_dynamics_walker(gait, options, rk4_steps, jit=True)
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
        Where the batches of each round are walked (:func:`analysis.tasks.resolve_scheduler`):
        None or 'synchronous', this process (the batches are vectorised); 'local', a
        LocalCluster; an address or a client, that cluster's workers (each builds the
        walker once).

    Returns
    -------
    BatchSStar
    """
    st = settings
    nd, nk = len(designs), len(dirs)
    M1 = np.array([d.M1 for d in designs], float)
    rj = np.array([d.rejoin for d in designs], float)
    used = 0

    def batches(idx, scales):
        for a in range(0, idx.size, chunk):
            part = idx[a:a + chunk]
            q0, dq0 = start_states(gait, np.tile(dirs, (part.size, 1)),
                                   np.repeat(scales[a:a + chunk], nk))
            yield part, (q0, dq0, np.repeat(M1[part], nk, axis=0), np.repeat(rj[part], nk))

    def walked(eng, idx, scales):
        if eng is None:
            for part, args in batches(idx, scales):
                yield part, walker.walk(*args, steps=st.steps)
            return
        parts = list(batches(idx, scales))
        out = dict(eng.each(walk_batch, {i: (gait, walker.options, walker.rk4_steps, *args,
                                             st.steps) for i, (_, args) in enumerate(parts)}))
        for i, (part, _) in enumerate(parts):
            yield part, out[i]

    where = "synchronous" if scheduler is None else resolve_scheduler(scheduler)
    with (Engine(where, cache=False) if where != "synchronous" else
          contextlib.nullcontext()) as eng:
        def evaluate(idx, scales):
            nonlocal used
            ok, info = [], []
            for part, B in walked(eng, idx, scales):
                used += B.scenario_steps
                for j in range(part.size):
                    b = B.take(slice(j * nk, (j + 1) * nk))
                    ok.append(_failure(b, st.tol) is None)
                    info.append((_cause(b, st.tol), float(np.mean(b.verdict(st.tol) == "ok"))))
            return np.array(ok), info

        lo, hi, _, at_hi = bisect_scale(evaluate, nd, st.s_max,
                                        st.rounds if rounds is None else rounds)
    cause = [c[0] if c is not None else "" for c in at_hi]
    frac = np.array([c[1] if c is not None else 1.0 for c in at_hi])
    best = float(lo.max()) if nd else 0.0
    return BatchSStar(lo, hi, cause, frac, used,
                      message=f"best s* {best:.4g} of {nd} designs over {nk} directions")
