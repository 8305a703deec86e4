"""How a run walked: one set of fields for every simulator, one verdict.

A run walks a number of steps from a start state and ends either 'ok' (every step
valid) or with the status of its first invalid state (:data:`STATUSES`).  Its outcome
(:class:`WalkOutcome`) is the same whichever simulator made it: the full-order
:class:`~biped_casadi.simulation.full_order.SimulationResult` is one (with logs and step
records besides), and a batch of runs on the walkers (:class:`WalkBatch`) holds the same
fields as arrays, one row per run (``batch[i]`` is run i's :class:`WalkOutcome`).

The error of a step is max(|q_u - q_u^d(T)|, |dq_u - dq_u^d(T)|) just before its impact.
A run that is 'ok' but whose last error is not below the tolerance has not converged
(:func:`verdict`).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import asdict, dataclass, field

import numpy as np

from ..results import Result, json_safe

__all__ = ["StepRecord", "STATUSES", "NOT_CONVERGED", "WalkOutcome", "WalkBatch", "verdict",
           "failure_text", "OutcomeRecorder"]

#: how a run ends: 'ok' (every step valid) or the first invalid state's status
STATUSES = ("ok", "fell", "scuffed", "negative_normal_force", "slipped", "torque_limit",
            "singular", "no_impact", "out_of_range", "diverged")
#: the verdict of a valid run whose last error is not below the tolerance
NOT_CONVERGED = "not_converged"


# ---------------------------------------------------------------- the verdicts
def _errors(qu_error, dqu_error):
    return np.maximum(np.abs(qu_error), np.abs(dqu_error))


def _final_error(status, qu_error, dqu_error):
    with np.errstate(invalid="ignore"):
        e = _errors(qu_error, dqu_error)[..., -1]
        return np.where((np.asarray(status) == "ok") & np.isfinite(e), e, np.inf)


def _steps_to_converge(status, qu_error, dqu_error, tol):
    with np.errstate(invalid="ignore"):
        below = _errors(qu_error, dqu_error) < tol
    # the first step of the trailing run of errors below tol (1-based)
    tail = np.flip(np.cumprod(np.flip(below, axis=-1), axis=-1), axis=-1).astype(bool)
    k = below.shape[-1] - tail.sum(axis=-1)
    return np.where((np.asarray(status) == "ok") & (k < below.shape[-1]), k + 1.0, np.nan)


def verdict(status, final_error, tol: float):
    """The verdict of runs: 'ok' (valid and converged), :data:`NOT_CONVERGED`, or the status.

    Parameters
    ----------
    status : str or array_like of str
        How the runs ended (:data:`STATUSES`).
    final_error : float or array_like
        The error at the last step (inf where the run failed).
    tol : float
        The convergence threshold, rad and rad/s.

    Returns
    -------
    str or numpy.ndarray of str
        Of the shape of ``status``.
    """
    status = np.asarray(status, dtype=object)
    with np.errstate(invalid="ignore"):
        out = np.where((status == "ok") & ~(np.asarray(final_error) < tol), NOT_CONVERGED,
                       status)
    return str(out) if out.ndim == 0 else out


def failure_text(status: str, fail_step: int) -> str:
    """How a run ended, in words for people: the step counted from 1.

    ``failure_text('slipped', 0)`` is 'slipped in step 1' (the first step, from the start
    state to the first impact), the row of that step in ``biped simulate``'s table;
    a run that walked every step but did not converge (:data:`NOT_CONVERGED`, whose
    ``fail_step`` is the number of steps) 'not_converged after step 10'.

    Parameters
    ----------
    status : str
        The run's verdict: 'ok', :data:`NOT_CONVERGED` or one of :data:`STATUSES`.
    fail_step : int
        The 0-based index of the failed step (``WalkOutcome.fail_step``); for 'ok' and
        :data:`NOT_CONVERGED` the number of steps walked.

    Returns
    -------
    str
    """
    if status in ("ok", NOT_CONVERGED):
        return f"{status} after step {int(fail_step)}"
    return f"{status} in step {int(fail_step) + 1}"


class _Verdicts:
    """The verdicts every outcome offers, on its fields (one run or a batch)."""

    @property
    def ok(self):
        """True where every step of the run was valid."""
        ok = np.asarray(self.status) == "ok"
        return bool(ok) if ok.ndim == 0 else ok

    @property
    def completed_steps(self):
        """Steps completed: each ends with a recorded impact (the failed one does not)."""
        k = np.sum(np.isfinite(np.asarray(self.duration)), axis=-1)
        return int(k) if np.ndim(k) == 0 else k

    def unactuated_errors(self):
        """``max(|q_u err|, |dq_u err|)`` before each completed step's impact.

        Returns
        -------
        numpy.ndarray
            (completed_steps,) for one run; (n, n_steps) with NaN after a failure for a
            batch.
        """
        e = _errors(self.qu_error, self.dqu_error)
        return e[:self.completed_steps] if np.ndim(e) == 1 else e

    @property
    def final_error(self):
        """``max(|q_u err|, |dq_u err|)`` at the last step; inf where the run failed."""
        e = _final_error(self.status, self.qu_error, self.dqu_error)
        return float(e) if np.ndim(e) == 0 else e

    def steps_to_converge(self, tol: float = 1e-3):
        """The step from which the error stays below ``tol`` to the end of the run.

        Parameters
        ----------
        tol : float
            Bound on max(``|q_u err|``, ``|dq_u err|``) just before each impact (rad,
            rad/s).

        Returns
        -------
        float or numpy.ndarray
            1-based index of that step; NaN where the run failed or never got there.
        """
        k = _steps_to_converge(self.status, self.qu_error, self.dqu_error, tol)
        return float(k) if np.ndim(k) == 0 else k

    def verdict(self, tol: float = 1e-3):
        """'ok' when valid and converged below ``tol``, :data:`NOT_CONVERGED`, or the status.

        Parameters
        ----------
        tol : float
            The convergence threshold, rad and rad/s.

        Returns
        -------
        str or numpy.ndarray of str
        """
        return verdict(self.status, self.final_error, tol)


@dataclass
class WalkOutcome(_Verdicts, Result):
    """How one run walked.

    ``success`` means the run was simulated (always, once the arguments were valid); the
    domain verdict is ``status`` ('ok' when every step was valid).  The per-step arrays
    have one entry per step asked for, NaN from the failed step on.

    Parameters
    ----------
    status : str
        One of :data:`STATUSES`.
    message : str
        What went wrong, naming the step counted from 1 ('step 1' is the first step, from
        the start state to the first impact); empty when 'ok'.
    n_steps : int
        Steps the run was to walk.
    fail_step : int
        The 0-based index of the step where the run failed (``n_steps`` when 'ok'); the
        message names it as step ``fail_step + 1``.
    qu_error : numpy.ndarray
        (n_steps,) q_u - q_u^d(T) just before each impact, rad.
    dqu_error : numpy.ndarray
        (n_steps,) dq_u - dq_u^d(T) just before each impact, rad/s.
    duration : numpy.ndarray
        (n_steps,) the duration of each step (tau at its impact), s.
    peak_torque : float
        The largest ``|u_i|`` of the run up to its end, N m.
    min_normal_force : float
        The smallest stance normal force F_z, N.
    max_friction_ratio : float
        The largest ``|F_x|/F_z`` in single support (inf where F_z <= 0).
    max_impulse_ratio : float
        The largest ``|F_x|/F_z`` of the impact impulses (inf where F_z <= 0).
    saturated_time : float
        Time the commanded torques spent beyond the limit, clipped there, s (0 unless
        the simulation saturates torques, ``SimulationOptions.saturate``).
    """

    status: str
    message: str
    n_steps: int
    fail_step: int
    qu_error: np.ndarray
    dqu_error: np.ndarray
    duration: np.ndarray
    peak_torque: float
    min_normal_force: float
    max_friction_ratio: float
    max_impulse_ratio: float
    saturated_time: float

    SUCCESS = STATUSES


#: the fields every outcome has, in order
OUTCOME_FIELDS = tuple(f.name for f in dataclasses.fields(WalkOutcome))


@dataclass
class WalkBatch(_Verdicts):
    """The outcomes of a batch of runs: the fields of :class:`WalkOutcome`, one row per run.

    ``batch[i]`` is the :class:`WalkOutcome` of run i; ``ok``, ``final_error``,
    ``steps_to_converge`` and ``verdict`` are those of every run, as arrays.
    ``success`` means the batch was walked (always).

    Parameters
    ----------
    status : numpy.ndarray
        (n,) how each run ended (:data:`STATUSES`).
    message : numpy.ndarray
        (n,) what went wrong in each run (empty when 'ok').
    n_steps : int
        Steps every run was to walk.
    fail_step : numpy.ndarray
        (n,) the 0-based index of the failed step (``n_steps`` when 'ok').
    qu_error, dqu_error, duration : numpy.ndarray
        (n, n_steps) as :class:`WalkOutcome`'s.
    peak_torque, min_normal_force, max_friction_ratio, max_impulse_ratio : numpy.ndarray
        (n,) as :class:`WalkOutcome`'s.
    saturated_time : numpy.ndarray
        (n,) as :class:`WalkOutcome`'s.
    scenario_steps : int
        The steps walked, summed over the runs.
    """

    status: np.ndarray
    message: np.ndarray
    n_steps: int
    fail_step: np.ndarray
    qu_error: np.ndarray
    dqu_error: np.ndarray
    duration: np.ndarray
    peak_torque: np.ndarray
    min_normal_force: np.ndarray
    max_friction_ratio: np.ndarray
    max_impulse_ratio: np.ndarray
    saturated_time: np.ndarray
    scenario_steps: int = 0

    success = True

    def __len__(self) -> int:
        return len(self.status)

    def __getitem__(self, i) -> WalkOutcome:
        return WalkOutcome(**{name: (getattr(self, name) if name == "n_steps" else
                                     _scalar(getattr(self, name)[i])) for name in OUTCOME_FIELDS})

    def take(self, rows) -> "WalkBatch":
        """The runs ``rows`` of the batch, as a batch.

        Parameters
        ----------
        rows : array_like of int or slice
            Which runs.

        Returns
        -------
        WalkBatch
        """
        kw = {name: (getattr(self, name) if name == "n_steps" else getattr(self, name)[rows])
              for name in OUTCOME_FIELDS}
        return WalkBatch(**kw, scenario_steps=0)

    @classmethod
    def concat(cls, batches) -> "WalkBatch":
        """One batch of the runs of several (of the same number of steps).

        Parameters
        ----------
        batches : sequence of WalkBatch or WalkOutcome
            In order; a :class:`WalkOutcome` (or a result that is one) counts as one run.

        Returns
        -------
        WalkBatch
        """
        parts = [b if isinstance(b, WalkBatch) else _one(b) for b in batches]
        kw = {name: np.concatenate([getattr(b, name) for b in parts])
              for name in OUTCOME_FIELDS if name != "n_steps"}
        return cls(n_steps=parts[0].n_steps, **kw,
                   scenario_steps=sum(b.scenario_steps for b in parts))

    def to_dict(self) -> dict:
        """The batch in JSON types: every field as a list (one entry per run).

        Returns
        -------
        dict
        """
        out = {name: json_safe(getattr(self, name)) for name in OUTCOME_FIELDS}
        out["scenario_steps"] = self.scenario_steps
        return out


def _one(o: WalkOutcome) -> WalkBatch:
    """A batch of one run."""
    kw = {name: np.asarray([getattr(o, name)]) for name in OUTCOME_FIELDS if name != "n_steps"}
    steps = int(np.sum(np.isfinite(o.duration))) + (0 if o.ok else 1)
    return WalkBatch(n_steps=o.n_steps, **kw, scenario_steps=min(steps, o.n_steps))


def _scalar(v):
    if isinstance(v, np.ndarray):
        return v.copy()
    if isinstance(v, np.bool_):
        return bool(v)
    if isinstance(v, np.integer):
        return int(v)
    if isinstance(v, np.floating):
        return float(v)
    return str(v) if isinstance(v, np.str_) else v


# ------------------------------------------------------------- accumulating
@dataclass
class OutcomeRecorder:
    """Accumulates the outcomes of n runs as a simulator walks them.

    Parameters
    ----------
    n : int
        Runs.
    n_steps : int
        Steps each run is to walk.
    """

    n: int
    n_steps: int
    status: np.ndarray = field(init=False)

    def __post_init__(self):
        n, k = self.n, self.n_steps
        self.status = np.full(n, "ok", dtype=object)
        self.message = np.full(n, "", dtype=object)
        self.fail_step = np.full(n, k)
        self.qu, self.dqu, self.dur = (np.full((n, k), np.nan) for _ in range(3))
        self.peak_u, self.min_fz, self.max_fr, self.max_ir = (np.full(n, np.nan)
                                                              for _ in range(4))
        self.sat_time = np.zeros(n)
        self.scenario_steps = 0

    def fail(self, runs, status, step, message=None):
        """Runs ``runs`` failed at step ``step`` with ``status`` (the first failure counts).

        Parameters
        ----------
        runs : array_like of int
            Indices of the runs.
        status : array_like of str
            Their statuses.
        step : int or array_like of int
            The step of the failure.
        message : array_like of str, optional
            What went wrong.
        """
        runs = np.atleast_1d(np.asarray(runs, int))
        first = self.status[runs] == "ok"
        r = runs[first]
        self.status[r] = np.broadcast_to(np.asarray(status, dtype=object), runs.shape)[first]
        self.fail_step[r] = np.broadcast_to(step, runs.shape)[first]
        if message is not None:
            self.message[r] = np.broadcast_to(np.asarray(message, dtype=object), runs.shape)[first]

    def track(self, runs, u, Fx, Fz, mask=None, saturated=None, dt=0.0):
        """Fold the nodes' torques and reactions into the runs' extremes.

        Parameters
        ----------
        runs : array_like of int
            (m,) indices of the runs.
        u : numpy.ndarray
            (nu, m, K) torques at K nodes of each run.
        Fx, Fz : numpy.ndarray
            (m, K) stance reaction.
        mask : numpy.ndarray, optional
            (m, K) the nodes that count (the run's nodes up to its end).
        saturated : numpy.ndarray, optional
            (m, K) 1 at the nodes where the torques were clipped at the limit.
        dt : float
            The time a node stands for (the integration step), s.
        """
        runs = np.atleast_1d(np.asarray(runs, int))
        if mask is None:
            mask = np.ones(Fz.shape, bool)
        if saturated is not None and dt:
            with np.errstate(invalid="ignore"):
                self.sat_time[runs] += dt * np.sum(mask & (saturated > 0.5), axis=1)
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            pu = np.where(mask, np.max(np.abs(u), axis=0), np.nan)
            # F_z <= 0: no friction cone holds the foot (inf, as for the impulses)
            # (a node that is not finite keeps NaN)
            ratio = np.where(mask, np.where(Fz <= 0, np.inf, np.abs(Fx) / Fz), np.nan)
            fz = np.where(mask, Fz, np.nan)
        self.peak_u[runs] = np.fmax(self.peak_u[runs], np.fmax.reduce(pu, axis=1))
        self.min_fz[runs] = np.fmin(self.min_fz[runs], np.fmin.reduce(fz, axis=1))
        self.max_fr[runs] = np.fmax(self.max_fr[runs], np.fmax.reduce(ratio, axis=1))

    def impact(self, runs, step, qu_err, dqu_err, duration, F):
        """Record the impacts of runs at step ``step``: errors before it, and its impulse.

        Parameters
        ----------
        runs : array_like of int
            (m,) indices of the runs.
        step : int
            The step.
        qu_err, dqu_err : array_like
            (m,) q_u - q_u^d(T) and dq_u - dq_u^d(T) just before the impact.
        duration : array_like
            (m,) tau at the impact, s.
        F : numpy.ndarray
            (m, 2) the impulse (F_x, F_z), N s.
        """
        runs = np.atleast_1d(np.asarray(runs, int))
        self.qu[runs, step], self.dqu[runs, step], self.dur[runs, step] = qu_err, dqu_err, duration
        F = np.atleast_2d(F)
        with np.errstate(invalid="ignore", divide="ignore"):
            ir = np.where(F[:, 1] > 0, np.abs(F[:, 0]) / F[:, 1], np.inf)
        self.max_ir[runs] = np.fmax(self.max_ir[runs], ir)

    def batch(self) -> WalkBatch:
        """The outcomes recorded so far.

        Returns
        -------
        WalkBatch
        """
        return WalkBatch(status=self.status.astype(str), message=self.message.astype(str),
                         n_steps=self.n_steps, fail_step=self.fail_step.copy(),
                         qu_error=self.qu, dqu_error=self.dqu, duration=self.dur,
                         peak_torque=self.peak_u, min_normal_force=self.min_fz,
                         max_friction_ratio=self.max_fr, max_impulse_ratio=self.max_ir,
                         saturated_time=self.sat_time.copy(),
                         scenario_steps=self.scenario_steps)

    def outcome(self, i: int = 0) -> dict:
        """The fields of run i's :class:`WalkOutcome`, as a dict (for a result that is one).

        Parameters
        ----------
        i : int
            The run.

        Returns
        -------
        dict
            Field name -> value.
        """
        b = self.batch()[i]
        return {name: getattr(b, name) for name in OUTCOME_FIELDS}


def nan_to_none(x):
    """``None`` for a NaN, the float otherwise (for JSON-facing fields)."""
    return None if x is None or (isinstance(x, float) and math.isnan(x)) else x


@dataclass
class StepRecord:
    """One completed step, from tau = 0 to its impact.

    Parameters
    ----------
    index : int
        The step's index (0-based).
    t_start, t_impact : float
        Time of its start and of its impact since the start of the run, s.
    duration : float
        tau at the impact, s.
    q_minus, dq_minus : numpy.ndarray
        The state just before the impact.
    q_plus, dq_plus : numpy.ndarray
        The state just after the impact and relabelling (the next step's start).
    impulse : numpy.ndarray
        (F_x, F_z) of the impact impulse on the new stance foot, N s.
    qu_error, dqu_error : float
        q_u - q_u^d(T) and dq_u - dq_u^d(T) just before the impact.
    section : numpy.ndarray or None
        (q_u, dq_u) at tau = 0.75 T (None if the impact came earlier).
    section_error : numpy.ndarray or None
        Its difference from the reference's (q_u^d, dq_u^d)(0.75 T).
    step_length : float
        x of the swing foot at the impact, m.
    ground_height : float
        The height h_k of the foothold the step struck, above its stance foot, m.
    """
    index: int
    t_start: float
    t_impact: float
    duration: float
    q_minus: np.ndarray
    dq_minus: np.ndarray
    q_plus: np.ndarray
    dq_plus: np.ndarray
    impulse: np.ndarray
    qu_error: float
    dqu_error: float
    section: np.ndarray | None
    section_error: np.ndarray | None
    step_length: float
    ground_height: float = 0.0

    def to_dict(self) -> dict:
        """Every field in plain JSON types.

        Returns
        -------
        dict
        """
        return json_safe(asdict(self))
