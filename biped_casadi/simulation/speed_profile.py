"""Walking a speed profile: one design per step, the gait switched at the impacts
(docs: theory, "Speed changes").

A profile (a *schedule*) is a sequence of designs, ``designs[k]`` the controller and gait
of step k.  Step k starts just after the impact that ended step k - 1 and runs on its own
gait: the time-varying controller's step start computes y_i, dy_i of eq. (17) against
its own reference at tau = 0 (so the correction v_c starts from the output errors
against the new gait), and virtual constraints start their phase-based correction on
their own constraint surface (:func:`~biped_casadi.control.phase_correction`).  Nothing
else carries over from one step to the next but the robot's state (q+, dq+) after the
impact and relabelling: the switch at an impact is a change of reference of the
hybrid system (eq. 9), exactly as the simulator of one gait starts each of its steps.

:func:`simulate_profile` walks the profile in full order with the
:class:`~biped_casadi.simulation.full_order.Simulator` of each design (built once per
distinct design, memoised), one step at a time from the state after the previous
impact, every node and impact checked by the simulator's validity machinery (contact,
friction cone incl. the impact impulse, scuffing, torque limit, singularity); the run
stops at the first invalid state.  A constant profile is the simulator's own run, step
for step (``tests/test_speed_changes.py`` checks it to round-off).  Per step it records
the step's speed and gait, its status, the errors against the step's own orbit just
before its impact (as :class:`~biped_casadi.simulation.full_order.StepRecord`), peak
torque and friction margin; per segment of equal designs, the steps it took to converge
to that gait.

:func:`walk_profile` does the same on the batched hybrid-zero-dynamics walkers
(:mod:`~biped_casadi.simulation.tv_walker`, :mod:`~biped_casadi.simulation.vc_walker`):
one walker per gait, one step at a time, every scenario carried from its post-impact
state to the next step's walker.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from ..control.design import Design
from ..control.reference import require_same_robot
from ..numerics import as_vector
from ..results import internal, json_safe
from .full_order import simulator
from .options import SimulationOptions
from .outcome import OutcomeRecorder, WalkBatch, WalkOutcome
from .tv_walker import zero_dynamics_walker
from .vc_walker import virtual_constraint_walker

__all__ = ["ProfileStep", "ProfileSegment", "ProfileResult", "simulate_profile",
           "walk_profile", "reference_speed", "CONVERGED"]

#: a step has converged to its gait when max(|q_u err|, |dq_u err|) is below this
CONVERGED = 1e-3


def reference_speed(gait) -> float:
    """The average forward speed of a reference step, m/s.

    Parameters
    ----------
    gait : Reference
        The reference (a :class:`gait_opt.Gait` has it as ``speed``).

    Returns
    -------
    float
        Step length / T: the swing foot's x at q^d(T) over T.
    """
    v = getattr(gait, "speed", None)
    if v is not None:
        return float(v)
    return float(np.asarray(gait.model.swing_foot(gait.q(gait.T))[0]).ravel()[0]) / gait.T


@dataclass
class ProfileStep:
    """One step of a speed profile (full order).

    Parameters
    ----------
    index : int
        The step (0-based).
    speed, T : float
        The step's gait: average speed (m/s) and duration (s).
    controller : dict
        The step's design (:meth:`Design.to_dict`): ``controller`` 'tv' or 'vc', ``M1``,
        ``rejoin``, ``gains``, ``gait`` (the gait's key).
    status : str
        'ok' when the step was valid to its impact (the impulse included), else the
        status of its first invalid state (:data:`~biped_casadi.simulation.STATUSES`).
    message : str
        What went wrong (empty when 'ok').
    qu_error, dqu_error : float
        q_u - q_u^d(T) and dq_u - dq_u^d(T) just before the impact, against the step's
        own gait (NaN without an impact).
    error : float
        max(``|qu_error|``, ``|dqu_error|``).
    section_error : list or None
        (q_u, dq_u) - (q_u^d, dq_u^d)(0.75 T) of the step's gait.
    duration : float
        tau at the impact, s (NaN without one).
    t_start : float
        Time of the step's start since the start of the profile, s.
    step_length : float
        x of the swing foot at the impact, m.
    peak_torque : float
        The largest ``|u_i|`` of the step, N m.
    torque_margin : float
        The smallest over the torques of the limit of u_i minus the step's largest
        ``|u_i|``, N m: the torque limit minus ``peak_torque`` where every joint has the
        same limit (negative: a limit was passed).
    min_normal_force : float
        The smallest stance F_z of the step, N.
    max_friction_ratio, max_impulse_ratio : float
        The largest ``|F_x| / F_z`` along the step and of its impact impulse.
    mu : float
        The friction coefficient the step was held to: the options' ``mu``, else its
        gait's own (:func:`~biped_casadi.simulation.options.friction_of`).
    friction_margin : float
        ``mu`` minus the larger of the two ratios (negative: the cone was left).
    q_plus, dq_plus : numpy.ndarray or None
        The state after the impact and relabelling (the next step's start); None when
        the step ended without a valid strike.
    """
    index: int
    speed: float
    T: float
    controller: dict
    status: str
    message: str
    qu_error: float
    dqu_error: float
    error: float
    section_error: list | None
    duration: float
    t_start: float
    step_length: float
    peak_torque: float
    torque_margin: float
    min_normal_force: float
    max_friction_ratio: float
    max_impulse_ratio: float
    mu: float
    friction_margin: float
    q_plus: np.ndarray | None = None
    dq_plus: np.ndarray | None = None

    def to_dict(self) -> dict:
        """Every field in plain JSON types.

        Returns
        -------
        dict
        """
        return json_safe({k: getattr(self, k) for k in self.__dataclass_fields__})


@dataclass
class ProfileSegment:
    """Consecutive steps of a profile on the same design (one gait).

    Parameters
    ----------
    speed : float
        The segment's speed, m/s.
    first_step : int
        Its first step (0-based; the step after the switch).
    n_steps : int
        Its steps in the profile.
    walked : int
        Of those, the steps completed validly.
    steps_to_converge : float
        1-based step of the segment from which the error against its gait stays below
        the tolerance to the segment's end (NaN if it never does, or the segment
        failed).
    first_error, final_error : float
        The error of its first and last completed step (NaN without one).
    """
    speed: float
    first_step: int
    n_steps: int
    walked: int
    steps_to_converge: float
    first_error: float
    final_error: float

    def to_dict(self) -> dict:
        """Every field in plain JSON types.

        Returns
        -------
        dict
        """
        return json_safe({k: getattr(self, k) for k in self.__dataclass_fields__})


@dataclass
class ProfileResult(WalkOutcome):
    """A speed profile walked in full order.

    The outcome fields (:class:`WalkOutcome`) are over the whole profile, the per-step
    errors each against its own step's gait; ``status`` 'ok' when every step was valid.

    Parameters
    ----------
    status, message, n_steps, fail_step, qu_error, dqu_error, duration : see WalkOutcome
    peak_torque, min_normal_force, max_friction_ratio, max_impulse_ratio : see WalkOutcome
    saturated_time : float
        See WalkOutcome.
    speeds : list of float
        The profile: the speed of each step's gait, m/s.
    steps : list of ProfileStep
        The steps walked (the failed one last).
    segments : list of ProfileSegment
        The runs of equal designs, with their convergence.
    tol : float
        The convergence tolerance of the segments, rad and rad/s.
    friction_margin : float
        mu minus the largest friction ratio of the profile (impulses included).
    options : SimulationOptions
        The options of the run.
    runs : list of SimulationResult
        The full-order run of each step, with its logs (left out of ``to_dict()``).
    """
    speeds: list = field(default_factory=list)
    steps: list = field(default_factory=list)
    segments: list = field(default_factory=list)
    tol: float = CONVERGED
    friction_margin: float = math.nan
    options: SimulationOptions | None = None
    runs: list = internal(default_factory=list)

    def errors(self) -> np.ndarray:
        """Per step, max(``|q_u err|``, ``|dq_u err|``) against the step's own gait.

        Returns
        -------
        numpy.ndarray
            (n_steps,), NaN from the failed step on (where it has no impact).
        """
        return np.maximum(np.abs(self.qu_error), np.abs(self.dqu_error))


# ------------------------------------------------------------------ profile input
def _designs(designs) -> list:
    """The profile's designs checked: a non-empty sequence, each on a gait of one robot;
    as (list of Design or controller, their keys)."""
    if isinstance(designs, (Design, str, bytes)) or not hasattr(designs, "__len__"):
        raise ValueError("designs: expected a sequence of designs, one per step")
    designs = list(designs)
    if not designs:
        raise ValueError("designs: the profile is empty (give one design per step)")
    out = []
    for k, d in enumerate(designs):
        if isinstance(d, Design):
            if d.gait is None:
                raise ValueError(f"designs[{k}]: a design without a gait")
            out.append(d)
        elif hasattr(d, "reference") and hasattr(d, "step_start"):
            out.append(d)
        else:
            raise ValueError(f"designs[{k}]: expected a Design (or a controller), got "
                             f"{type(d).__name__}")
    model = _gait(out[0]).model
    for k, d in enumerate(out[1:], 1):
        try:
            require_same_robot(model, _gait(d))
        except ValueError:
            raise ValueError(f"designs[{k}]: its gait is of another robot than the first "
                             "step's (designs[0])") from None
    return out


def _gait(d):
    return d.gait if isinstance(d, Design) else d.reference


def _key(d):
    return d.cache_key


def _controller(d):
    return d.controller_for() if isinstance(d, Design) else d


def _start(q0, dq0, gait):
    nq = gait.model.nq
    q = gait.q(0.0) if q0 is None else q0
    dq = gait.dq(0.0) if dq0 is None else dq0
    return as_vector(q, nq, "q0"), as_vector(dq, nq, "dq0")


# --------------------------------------------------------------------- full order
def simulate_profile(designs, q0=None, dq0=None, options: SimulationOptions | None = None,
                     plant=None, tol: float = CONVERGED) -> ProfileResult:
    """Walk a speed profile in full order: step k on ``designs[k]`` (module docstring).

    Parameters
    ----------
    designs : sequence of Design
        One design per step, each on its gait (all of one robot); or the controllers.
    q0, dq0 : array_like, optional
        The state at the start of the first step (tau = 0); default its gait at tau = 0.
    options : SimulationOptions, optional
        Validity thresholds and integration (``steps`` is ignored: the profile has
        ``len(designs)`` steps).
    plant : BipedModel, optional
        The robot that moves, when it differs from the controllers' model.
    tol : float
        Convergence tolerance of the segments, rad and rad/s.

    Returns
    -------
    ProfileResult

    Raises
    ------
    ValueError
        Naming ``designs``, ``q0``/``dq0``, ``options`` or ``tol``.
    """
    ds = _designs(designs)
    opts = options if options is not None else SimulationOptions()
    if not isinstance(opts, SimulationOptions):
        raise ValueError(f"options must be a SimulationOptions, got {type(opts).__name__}")
    if not (isinstance(tol, (int, float)) and math.isfinite(tol) and tol > 0):
        raise ValueError(f"tol must be a positive number, got {tol!r}")
    q, dq = _start(q0, dq0, _gait(ds[0]))
    sims, steps, runs = {}, [], []
    t0 = 0.0
    for k, d in enumerate(ds):
        key = _key(d)
        if key not in sims:
            sims[key] = simulator(_controller(d), opts, plant)
        sim = sims[key]
        res = sim.run(q, dq, steps=1)
        runs.append(res)
        step = _profile_step(k, d, sim, res, t0)
        steps.append(step)
        if step.status != "ok":
            break
        t0 += step.duration
        q, dq = step.q_plus, step.dq_plus
    return _result(ds, steps, runs, opts, tol)


def _profile_step(k, d, sim, res, t0) -> ProfileStep:
    """The record of step k from the simulator's one-step run ``res``."""
    rec = res.steps[0] if res.steps else None
    g = sim.gait
    message = re.sub(r"^step \d+: ", "", res.message)
    nan = math.nan
    qe = rec.qu_error if rec is not None else nan
    dqe = rec.dqu_error if rec is not None else nan
    ratios = [r for r in (res.max_friction_ratio, res.max_impulse_ratio) if math.isfinite(r)]
    desc = d.to_dict() if isinstance(d, Design) else dict(sim.controller.describe())
    return ProfileStep(
        index=k, speed=reference_speed(g), T=float(g.T), controller=desc,
        status=res.status, message=f"step {k + 1}: {message}" if message else "",
        qu_error=float(qe), dqu_error=float(dqe), error=float(max(abs(qe), abs(dqe))),
        section_error=None if rec is None or rec.section_error is None
        else [float(x) for x in rec.section_error],
        duration=float(rec.duration) if rec is not None else nan, t_start=float(t0),
        step_length=float(rec.step_length) if rec is not None else nan,
        peak_torque=float(res.peak_torque),
        torque_margin=_torque_margin(sim.torque_limit, res.u),
        min_normal_force=float(res.min_normal_force),
        max_friction_ratio=float(res.max_friction_ratio),
        max_impulse_ratio=float(res.max_impulse_ratio),
        mu=float(sim.limits.mu),
        friction_margin=float(sim.limits.mu - max(ratios)) if ratios else nan,
        q_plus=None if rec is None else rec.q_plus.copy(),
        dq_plus=None if rec is None else rec.dq_plus.copy())


def _torque_margin(limit, u) -> float:
    """min over i of (U_i - max |u_i|) over the logged nodes ``u`` (N, nu) of a step, the
    nodes its ``peak_torque`` is the largest ``|u_i|`` of (NaN without one)."""
    if u.size == 0:
        return math.nan
    peaks = np.fmax.reduce(np.abs(u), axis=0)    # as the run's peak: NaN nodes left out
    return float(np.min(np.asarray(limit, float) - peaks))


def _result(ds, steps, runs, opts, tol) -> ProfileResult:
    n = len(ds)
    qu, dqu, dur = (np.full(n, np.nan) for _ in range(3))
    for s in steps:
        if s.status == "ok" or math.isfinite(s.qu_error):
            qu[s.index], dqu[s.index], dur[s.index] = s.qu_error, s.dqu_error, s.duration
    last = steps[-1]
    failed = last.status != "ok"

    def ext(fn, name):
        vals = [getattr(s, name) for s in steps if math.isfinite(getattr(s, name))]
        return float(fn(vals)) if vals else math.nan

    speeds = [reference_speed(_gait(d)) for d in ds]
    return ProfileResult(
        status=last.status if failed else "ok", message=last.message if failed else "",
        n_steps=n, fail_step=last.index if failed else n, qu_error=qu, dqu_error=dqu,
        duration=dur, peak_torque=ext(max, "peak_torque"),
        min_normal_force=ext(min, "min_normal_force"),
        max_friction_ratio=ext(max, "max_friction_ratio"),
        max_impulse_ratio=ext(max, "max_impulse_ratio"),
        saturated_time=float(sum(r.saturated_time for r in runs)),
        speeds=speeds, steps=steps, segments=segments(ds, speeds, qu, dqu, len(steps),
                                                      failed, tol),
        tol=float(tol), friction_margin=ext(min, "friction_margin"),
        options=opts, runs=runs)


def segments(designs, speeds, qu_error, dqu_error, walked: int, failed: bool,
             tol: float = CONVERGED) -> list:
    """The runs of equal consecutive designs of a profile, with their convergence.

    Parameters
    ----------
    designs : sequence
        The profile's designs (compared by their keys).
    speeds : sequence of float
        Each step's speed, m/s.
    qu_error, dqu_error : array_like
        (n,) each step's errors against its own gait (NaN where not walked).
    walked : int
        The steps simulated (the failed one included).
    failed : bool
        Whether the last simulated step failed.
    tol : float
        Convergence tolerance.

    Returns
    -------
    list of ProfileSegment
    """
    keys = [_key(d) for d in designs]
    e = np.maximum(np.abs(np.asarray(qu_error, float)), np.abs(np.asarray(dqu_error, float)))
    out, start = [], 0
    for k in range(1, len(keys) + 1):
        if k < len(keys) and keys[k] == keys[start]:
            continue
        seg = e[start:k]
        done = max(0, min(k, walked - (1 if failed else 0)) - start)
        ok = done == k - start
        with np.errstate(invalid="ignore"):
            below = seg[:done] < tol
        tail = int(np.flip(np.cumprod(np.flip(below))).sum()) if done else 0
        out.append(ProfileSegment(
            speed=float(speeds[start]), first_step=start, n_steps=k - start, walked=done,
            steps_to_converge=float(done - tail + 1) if ok and tail > 0 else math.nan,
            first_error=float(seg[0]) if done else math.nan,
            final_error=float(seg[done - 1]) if done else math.nan))
        start = k
    return out


# ------------------------------------------------------------------------ walkers
def walk_profile(designs, q0=None, dq0=None, options: SimulationOptions | None = None,
                 rk4_steps: int = 400, nodes: int = 200, jit: bool = False) -> WalkBatch:
    """Walk a speed profile on the batched zero-dynamics walkers, from n start states.

    Step k of every scenario runs on the walker of ``designs[k]``'s gait (the
    time-varying walker with its M1 and rejoin, or the virtual-constraint walker), from
    the scenario's state after the impact of step k - 1: one walker per gait, one step
    at a time.  Exact on the hybrid zero dynamics of every step (each walker's own
    claim), to the walkers' integration accuracy.

    Parameters
    ----------
    designs : sequence of Design
        One design per step (module docstring), all of one controller kind or mixed.
    q0, dq0 : array_like, optional
        (n, nq) start states (tau = 0 of the first step); default its gait at tau = 0.
    options : SimulationOptions, optional
        Validity thresholds.
    rk4_steps : int
        RK4 steps per T of the time-varying walkers.
    nodes : int
        RK4 nodes per step of the virtual-constraint walkers.
    jit : bool
        Compile the walkers.

    Returns
    -------
    WalkBatch
        One row per scenario; the per-step errors against each step's own gait.
    """
    ds = _designs(designs)
    if not all(isinstance(d, Design) for d in ds):
        raise ValueError("designs: the walkers take Designs (not controllers)")
    g0 = ds[0].gait
    nq = g0.model.nq
    q = np.atleast_2d(np.asarray(g0.q(0.0) if q0 is None else q0, float))
    dq = np.atleast_2d(np.asarray(g0.dq(0.0) if dq0 is None else dq0, float))
    if q.shape[1] != nq or dq.shape[1] != nq:
        raise ValueError(f"q0, dq0: expected (n, {nq}) start states")
    n = max(len(q), len(dq))
    q, dq = np.broadcast_to(q, (n, nq)).copy(), np.broadcast_to(dq, (n, nq)).copy()
    rec = OutcomeRecorder(n, len(ds))
    alive = np.ones(n, bool)
    impact = _impact_map(g0.model, n)
    for k, d in enumerate(ds):
        idx = np.flatnonzero(alive)
        if idx.size == 0:
            break
        rec.scenario_steps += idx.size
        if d.M1 is None:
            w = virtual_constraint_walker(d.gait, options, nodes, jit)
            b, qm, dqm = w.walk_step(q[idx], dq[idx])
        else:
            w = zero_dynamics_walker(d.gait, options, rk4_steps, jit)
            b, qm, dqm = w.walk_step(q[idx], dq[idx], np.array(d.M1), d.rejoin)
        _fold(rec, idx, k, b)
        bad = ~b.ok
        alive[idx[bad]] = False
        go = idx[~bad]
        if go.size and k + 1 < len(ds):
            qp, dqp = impact(qm[~bad], dqm[~bad])
            q[go], dq[go] = qp, dqp
    return rec.batch()


def _fold(rec: OutcomeRecorder, idx, k: int, b: WalkBatch):
    """Record the one-step batch ``b`` of scenarios ``idx`` as step k of the profile."""
    rec.qu[idx, k], rec.dqu[idx, k], rec.dur[idx, k] = (b.qu_error[:, 0], b.dqu_error[:, 0],
                                                       b.duration[:, 0])
    rec.peak_u[idx] = np.fmax(rec.peak_u[idx], b.peak_torque)
    rec.min_fz[idx] = np.fmin(rec.min_fz[idx], b.min_normal_force)
    rec.max_fr[idx] = np.fmax(rec.max_fr[idx], b.max_friction_ratio)
    rec.max_ir[idx] = np.fmax(rec.max_ir[idx], b.max_impulse_ratio)
    bad = ~b.ok
    rec.fail(idx[bad], b.status[bad], k, np.array(  # the walker's one step is step k + 1
        [f"step {k + 1}: {m.removeprefix('step 1: ')}" if m else "" for m in b.message[bad]],
        dtype=object))


def _impact_map(model, n: int):
    """(q-, dq-) -> (q+, dq+) of m <= n scenarios (the impact and relabelling, eq. 2-3)."""
    f = model.impact_full
    q, dq = ca.SX.sym("q", model.nq), ca.SX.sym("dq", model.nq)
    qp, dqp = f(q, dq)[:2]
    one = ca.Function("impact_relabel", [q, dq], [qp, dqp])

    def call(qm, dqm):
        m = len(qm)
        if m == 0:
            return qm, dqm
        out = one.map(m)(qm.T, dqm.T)
        return np.array(out[0]).T, np.array(out[1]).T
    return call

