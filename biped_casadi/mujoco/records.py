"""What a walk in MuJoCo records: one :class:`MujocoStep` per step, the
:class:`MujocoWalk` of a run, and the log of its states."""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from ..results import Result, internal, json_safe

__all__ = ["MujocoStep", "MujocoWalk"]


@dataclass
class MujocoStep:
    """One step walked in MuJoCo, from its start to its touchdown.

    Parameters
    ----------
    index : int
        0-based.
    t_start, t_touchdown : float
        Time of its start and of its touchdown since the walk began, s.
    period : float
        Its duration, s.
    step_length : float
        Horizontal distance from the stance foot's touchdown to the swing foot's, m.
    speed : float
        step_length / period, m/s.
    speed_error, period_error : float
        Relative to the gait's speed and step duration T.
    qu_error, dqu_error : float
        q_u - q_u^d(T) and dq_u - dq_u^d(T) at the touchdown state (rad, rad/s).
    q_minus, dq_minus : list of float
        The touchdown state in the toolkit's coordinates (before relabelling).
    peak_commanded, peak_applied : float
        Largest torque the law asked for, and MuJoCo applied (clipped at the limit), N m.
    clipped_time : float
        Time some commanded torque exceeded the limit, s.
    slip : float
        How far the stance foot's sphere slid on the floor in single support (after the
        old stance foot's lift-off, while in contact: its centre's travel less the rolling
        r dphi), m.  It includes the rest of the landing's skid when the old foot lifts
        off before MuJoCo's contact has stopped the new one (at MuJoCo's default contact
        most of it: docs/howto/mujoco.md).
    liftoff : float
        tau at which the old stance foot lifted off, s.
    impact_travel : float
        How far the stance foot's sphere moved otherwise: from its touchdown to that
        lift-off (MuJoCo's soft impact stopping it) and while it was off the ground, m.
    airborne_time : float
        Time the stance foot spent off the ground in single support (a bounce after the
        touchdown), s.
    section : list of float or None
        (q_u, dq_u) at tau = 0.75 T, the Poincaré section of A^z (interpolated between
        MuJoCo's steps); None when the touchdown came earlier.
    section_error : list of float or None
        Its difference from the gait's (q_u^d, dq_u^d)(0.75 T).
    """

    index: int
    t_start: float
    t_touchdown: float
    period: float
    step_length: float
    speed: float
    speed_error: float
    period_error: float
    qu_error: float
    dqu_error: float
    q_minus: list
    dq_minus: list
    peak_commanded: float
    peak_applied: float
    clipped_time: float
    slip: float
    liftoff: float
    impact_travel: float
    airborne_time: float
    section: list | None = None
    section_error: list | None = None

    def to_dict(self) -> dict:
        """Every field in JSON types.

        Returns
        -------
        dict
        """
        return json_safe(asdict(self))


@dataclass
class MujocoWalk(Result):
    """A walk in MuJoCo.

    Parameters
    ----------
    status : str
        One of :data:`OUTCOMES`; ``success`` means 'walked'.
    message : str
        Why the walk stopped, naming the step (empty when it walked).
    n_steps : int
        Steps asked for.
    steps_walked : int
        Touchdowns reached.
    fail_step : int
        0-based index of the step where the walk stopped (``n_steps`` when it walked): a
        failure at a touchdown (a slip beyond the limit) is the step that touchdown ends,
        as in the Python simulator; ``message`` names it counted from 1
        (:func:`~biped_casadi.simulation.failure_text`).
    speed_error, period_error : float
        Relative error of the mean speed and the mean step duration over the steps after
        :data:`SETTLE` (all the steps when there are fewer than 2 SETTLE), NaN with none.
    worst_qu_error, worst_dqu_error : float
        Largest ``|q_u - q_u^d(T)|`` and ``|dq_u - dq_u^d(T)|`` at touchdown after
        step :data:`SETTLE` (NaN with fewer steps).
    peak_commanded, peak_applied, clipped_time, max_slip : float
        Over the walk: N m, N m, s, m.
    max_penetration : float
        The deepest either foot's sphere went into the floor over the walk (its radius
        less the lowest height of its centre, 0 when no foot went below the floor's
        surface), m: MuJoCo's soft contact lets a foot sink, deeper with a softer
        contact.
    settings : dict
        The MuJoCo settings (:class:`~biped_casadi.mujoco.mjcf.ContactSettings`).
    design : dict
        The design's ``to_dict()``.
    law : str
        'c' or 'python'.
    step_start : str
        'impact' or 'contact'.
    touchdown : str
        'grid' or 'interpolated'.
    torque_limit : float
        The motors' limit, N m.
    gait : dict
        The gait's ``T``, ``speed``, ``step_length``, ``qu_T``, ``dqu_T``.
    steps : list of MujocoStep
    mujoco_steps : int
        MuJoCo steps taken.
    wall_time : float
        Seconds.
    t : numpy.ndarray
        (N,) time of each logged state, s (empty without ``log``).
    qpos, qvel : numpy.ndarray
        (N, 3 + 2 k) MuJoCo's coordinates and velocities.
    stance : numpy.ndarray
        (N,) the stance leg, 0 (a) or 1 (b).
    u : numpy.ndarray
        (N, nu) the commanded torques, N m.
    """

    status: str
    message: str
    n_steps: int
    steps_walked: int
    fail_step: int
    speed_error: float
    period_error: float
    worst_qu_error: float
    worst_dqu_error: float
    peak_commanded: float
    peak_applied: float
    clipped_time: float
    max_slip: float
    max_penetration: float
    settings: dict
    design: dict
    law: str
    step_start: str
    touchdown: str
    torque_limit: float
    gait: dict
    steps: list
    mujoco_steps: int
    wall_time: float
    t: np.ndarray = internal()
    qpos: np.ndarray = internal()
    qvel: np.ndarray = internal()
    stance: np.ndarray = internal()
    u: np.ndarray = internal()

    SUCCESS = ("walked",)

    @property
    def speeds(self) -> np.ndarray:
        """Speed of every step, m/s."""
        return np.array([s.speed for s in self.steps])

    @property
    def errors(self) -> np.ndarray:
        """(steps, 2): q_u and dq_u errors at every touchdown."""
        return np.array([[s.qu_error, s.dqu_error] for s in self.steps]).reshape(-1, 2)

    @property
    def pre_impact_states(self) -> np.ndarray:
        """(steps, 2 nq): (q-, dq-) at every touchdown (the toolkit's coordinates)."""
        return np.array([s.q_minus + s.dq_minus for s in self.steps])

    @property
    def landing_travel(self) -> float:
        """The largest ``|impact_travel|`` of steps 2 on (the worst landing), m.

        Step 1's stance foot did not land in the walk; NaN with fewer than two steps.
        """
        return max((abs(s.impact_travel) for s in self.steps[1:]), default=math.nan)

    @property
    def steps_per_second(self) -> float:
        """MuJoCo steps per second of wall time (with the law in the loop)."""
        return self.mujoco_steps / self.wall_time if self.wall_time > 0 else math.nan


def _pair(x, minus=None):
    if x is None:
        return None
    if minus is None:
        return [float(x[0]), float(x[1])]
    return [float(x[0]) - minus[0], float(x[1]) - minus[1]]


class _Log:
    """Preallocated rows of the walk's log, grown when full."""

    def __init__(self, rows: int, n: int, nu: int, on: bool):
        self.on, self.k = on, 0
        rows = rows if on else 0
        self.t, self.qpos, self.qvel = np.zeros(rows), np.zeros((rows, n)), np.zeros((rows, n))
        self.stance, self.u = np.zeros(rows, np.int8), np.zeros((rows, nu))

    def add(self, t, qpos, qvel, stance, u):
        if self.k == self.t.size:
            for name in ("t", "qpos", "qvel", "stance", "u"):
                a = getattr(self, name)
                setattr(self, name, np.concatenate([a, np.zeros_like(a)]))
        k = self.k
        self.t[k], self.stance[k] = t, stance
        self.qpos[k] = qpos
        self.qvel[k] = qvel
        self.u[k] = u
        self.k = k + 1

    def arrays(self):
        k = self.k
        return self.t[:k], self.qpos[:k], self.qvel[:k], self.stance[:k], self.u[:k]
