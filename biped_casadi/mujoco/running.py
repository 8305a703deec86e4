"""A running gait in MuJoCo: the tracking controller of
:class:`~biped_casadi.control.running.RunningController` with MuJoCo's contacts deciding
the phases.

The robot is the MJCF of :func:`~biped_casadi.mujoco.mjcf.mjcf` (sphere feet, the
settings of :class:`~biped_casadi.mujoco.mjcf.ContactSettings`).  A run starts at a
stance state just after a landing (the exact stride map's fixed point, perturbed or not:
``running_stability(cycle).fixed_point``), the stance foot's sphere on the floor at
x = 0 and at rest.  Every MuJoCo step the controller's law (its CasADi Functions,
called from Python) gives the torques at MuJoCo's state, read in the toolkit's
coordinates with the current stance leg (:class:`~biped_casadi.mujoco.mjcf.Layout`),
and the time since the phase began; they are held over the step (MuJoCo's motors clip
them at the torque limit).  In flight the law takes the extended state qe = (q, x, z)
of the leg that pushed off (its foot's point as the base, relative to where it left
the ground).

The phases come from MuJoCo's contacts.  As in the walking loop
(:mod:`~biped_casadi.mujoco.walk`), the contacts and forces MuJoCo reports after a step
are those of the state the step started from, so a switch is dated at that state:

- stance -> flight: the stance foot's normal contact force (``mj_contactForce``, summed
  over its contacts) is zero and stays so for ``liftoff_time`` with the sphere at least
  ``liftoff_height`` above the floor; the flight clock starts at the first of those
  zero-force states.  At stiff contact the loaded foot chatters (its contact drops for
  single time steps all along the stance, more often as the force falls), hence the
  confirmation; a loss of contact before ``min_stance`` of the gait's stance is a bounce
  off the landing (recorded as ``bounce_time``), not a takeoff;
- flight -> stance: the swing foot's first contact.  Its time and state are
  interpolated between that state and the one before to where the sphere meets the
  floor; the legs are relabelled and the stance clock starts there.

MuJoCo's impact is soft and takes a few milliseconds: the run never jumps the state.
What is compared with the exact stride map is the *landing state*: the rigid landing
map (``landing_swing``: impact and relabelling, the exact map's reset) applied to
MuJoCo's state at the touchdown, a stance state (q, dq) like the exact map's.

A run ends 'ran' after its strides, or at the first of (:data:`RUN_OUTCOMES`): 'fell'
(hip below ``fall_height`` above the feet' level, torso past horizontal), 'slipped'
(the stance foot sliding more than ``max_slip`` in a stance: its centre's travel less
the rolling r dphi), 'phase_too_long' (a stance or a flight lasting ``time_limits``
times the gait's), 'double_contact' (the foot that pushed off touching the floor again
in flight, or the swing foot touching it in stance), 'saturated' (with ``stop_on_saturation``: a commanded torque beyond the
limit) and 'diverged' (MuJoCo's state or the torque not finite).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..control.running import RunningController
from ..model import flight_model
from ..model.description import torso_lean
from ..numerics import FastCall
from ..results import Result
from .mjcf import STIFF, ContactSettings, layout, mjcf, torque_limit_of

__all__ = ["RUN_OUTCOMES", "RunningLoop", "MujocoRun", "RunningStride", "run_in_mujoco",
           "decay_rate", "fit_running_map", "RunningMapFit"]

#: how a run ends: 'ran', or the reason it stopped (module docstring)
RUN_OUTCOMES = ("ran", "fell", "slipped", "phase_too_long", "double_contact", "saturated",
                "diverged")
_HALF_PI = math.pi / 2


def _mujoco():
    import mujoco
    return mujoco


@dataclass
class RunningStride:
    """One stride in MuJoCo, landing to landing (SI units).

    Parameters
    ----------
    index : int
        0-based.
    t_landing : float
        MuJoCo's time at the landing that starts it, s.
    stance, flight : float
        The phases' durations, s.
    step_length : float
        The landing foot's x less the previous landing foot's, m.
    speed : float
        step_length / (stance + flight), m/s.
    landing_state : list of float
        The rigid landing map of MuJoCo's state at the stride's closing touchdown: the next
        stance state (q, dq), as the exact stride map's.
    deviation : float
        max ``|landing_state - x*|`` (rad, rad/s).
    peak_torque : float
        Largest ``|u|`` commanded over the stride, N m.
    clipped_time : float
        Time with a commanded torque beyond the limit (MuJoCo clips it), s.
    slip : float
        The stance foot's sliding in the stance, m.
    fz_max : float
        Largest normal force on the stance foot, N (MuJoCo's soft landing shows here).
    bounce_time : float
        Time the stance foot spent off the floor early in the stance (a bounce off the
        landing, before ``min_stance`` of the gait's stance), s.
    """

    index: int
    t_landing: float
    stance: float
    flight: float
    step_length: float
    speed: float
    landing_state: list
    deviation: float
    peak_torque: float
    clipped_time: float
    slip: float
    fz_max: float
    bounce_time: float = 0.0

    def to_dict(self) -> dict:
        """The stride's figures by name.

        Returns
        -------
        dict
        """
        return dict(self.__dict__)


@dataclass
class MujocoRun(Result):
    """A run of the running controller in MuJoCo.

    Parameters
    ----------
    status, message : str
        'ran' or the reason it stopped (:data:`RUN_OUTCOMES`), and a summary line.
    n_strides : int
        Strides asked for.
    strides : list of RunningStride
        The completed strides.
    start : list of float
        The stance state the run started from.
    fixed_point : list of float
        x*, the exact map's fixed point the deviations are measured from.
    deviations : list of float
        max ``|x_k - x*|``: the start's, then each stride's landing state's.
    gait : dict
        The gait's ``T_stance``, ``T_flight``, ``speed``, ``step_length``.
    controller : dict
        ``law``, ``Kp``, ``Kd``, ``M1``, ``saturate``.
    settings : dict
        MuJoCo's settings.
    torque_limit : float
        N m.
    mujoco_steps : int
        MuJoCo steps taken.
    wall_time : float
        s.
    t, qpos, qvel, phase : numpy.ndarray
        The log with ``log=True`` (every MuJoCo state; phase 0 stance, 1 flight), else
        empty; not in ``to_dict()``.
    stance_leg : numpy.ndarray
        The stance leg at each logged state (0: a, 1: b).
    """

    status: str
    message: str
    n_strides: int
    strides: list
    start: list
    fixed_point: list
    deviations: list
    gait: dict
    controller: dict
    settings: dict
    torque_limit: float
    mujoco_steps: int
    wall_time: float
    t: np.ndarray = field(default_factory=lambda: np.zeros(0), metadata={"dict": False})
    qpos: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)), metadata={"dict": False})
    qvel: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)), metadata={"dict": False})
    phase: np.ndarray = field(default_factory=lambda: np.zeros(0), metadata={"dict": False})
    stance_leg: np.ndarray = field(default_factory=lambda: np.zeros(0),
                                   metadata={"dict": False})

    SUCCESS = ("ran",)

    @property
    def strides_run(self) -> int:
        """Completed strides."""
        return len(self.strides)

    @property
    def landing_states(self) -> np.ndarray:
        """(strides + 1, 2 nq): the start, then each stride's landing state."""
        return np.array([self.start] + [s.landing_state for s in self.strides], float)

    def to_dict(self) -> dict:
        """Plain JSON types, with the run's summary figures.

        Returns
        -------
        dict
            The fields, ``strides_run``, the mean speed and durations over the last two
            thirds of the strides and the decay of the deviation (:func:`decay_rate`).
        """
        d = super().to_dict()
        d["strides_run"] = self.strides_run
        late = self.strides[len(self.strides) // 3:]
        for k in ("speed", "stance", "flight"):
            d[f"mean_{k}"] = float(np.mean([getattr(s, k) for s in late])) if late \
                else math.nan
        d["decay"] = decay_rate(self)
        from ..results import json_safe
        return json_safe(d)


def decay_rate(run: MujocoRun, skip: int = 1) -> dict:
    """How fast a run's landing states settle, per stride.

    Two distances per landing state: from the exact fixed point x* (``deviations``) and
    from MuJoCo's own cycle, the mean landing state over the last third of the run.  The
    rate is exp of the slope of a least-squares line through log(distance to MuJoCo's
    cycle) over the strides from ``skip`` on while that distance is above three times the
    cycle's spread (the jitter: the largest distance of a last-third landing state from
    the mean; below it the deviation is the time grid's noise, not the map's modes).

    Parameters
    ----------
    run : MujocoRun
        The run.
    skip : int
        Strides left out at the start (the first stride moves a perturbation onto the map's
        modes).

    Returns
    -------
    dict
        ``rate`` (NaN when fewer than three strides are above the floor), ``strides_fitted``,
        ``cycle_offset`` (max ``|mean - x*|``: MuJoCo's cycle against the exact one),
        ``jitter``, ``to_cycle`` (the distances to MuJoCo's cycle).
    """
    X = run.landing_states
    xs = np.asarray(run.fixed_point, float)
    nan = dict(rate=math.nan, strides_fitted=0, cycle_offset=math.nan, jitter=math.nan,
               to_cycle=[])
    if len(X) < 6:
        return nan
    tail = X[len(X) - max(2, (len(X) - 1) // 3):]
    mean = tail.mean(axis=0)
    jitter = float(np.max(np.abs(tail - mean)))
    d = np.max(np.abs(X - mean), axis=1)
    k = np.arange(len(d))
    ok = (k >= skip) & (d > 3 * jitter)
    # the fit stops at the first stride below the floor
    last = skip
    while last < len(d) and ok[last]:
        last += 1
    sel = np.arange(skip, last)
    rate = math.nan
    if sel.size >= 3:
        slope = np.polyfit(sel, np.log(d[sel]), 1)[0]
        rate = float(math.exp(slope))
    return dict(rate=rate, strides_fitted=int(sel.size),
                cycle_offset=float(np.max(np.abs(mean - xs))), jitter=jitter,
                to_cycle=d.tolist())


@dataclass
class RunningMapFit(Result):
    """MuJoCo's running stride map fitted from the landing states of a run.

    Parameters
    ----------
    status, message : str
        'ok', or 'failed' (too few strides for the fit).
    A : list
        The (n, n) Lambda of the least-squares fit x_{k+1} = c + Lambda x_k.
    eigenvalues : list
        Its eigenvalues by decreasing modulus.
    max_abs : float
        Their largest modulus.
    max_abs_spread : float
        Standard deviation of max|lambda| over 200 bootstrap resamples of the pairs
        (seeded).
    relative_residual : float
        RMS residual over the RMS spread of x_{k+1}, the largest over the components:
        the share of the next landing state the map does not explain (MuJoCo's jitter).
    pairs : int
        (x_k, x_{k+1}) pairs fitted.
    """

    status: str
    message: str
    A: list
    eigenvalues: list
    max_abs: float
    max_abs_spread: float
    relative_residual: float
    pairs: int

    SUCCESS = ("ok",)


def fit_running_map(runs, skip: int = 1, seed: int = 0) -> RunningMapFit:
    """MuJoCo's stride map from runs: a least-squares fit of x_{k+1} = c + Lambda x_k.

    At stiff contact MuJoCo's landing states do not repeat: each stride adds a jitter of
    tenths of a rad/s (the contact's chatter, the time grid) that a perturbation meets
    after a stride or two, so a decay cannot be read off one perturbed run.  The jitter
    keeps the state moving about MuJoCo's cycle; over a long run the pairs of
    consecutive landing states determine the linear map as an autoregression does (the
    jitter enters as noise independent of x_k).

    Parameters
    ----------
    runs : MujocoRun or list of MujocoRun
        Runs of one loop (their completed strides).
    skip : int
        Landing states left out at the start of each run (the start itself, a transient).
    seed : int
        Of the bootstrap.

    Returns
    -------
    RunningMapFit
    """
    runs = [runs] if isinstance(runs, MujocoRun) else list(runs)
    P0, P1 = [], []
    for r in runs:
        X = r.landing_states[skip:]
        if len(X) > 1:
            P0.append(X[:-1])
            P1.append(X[1:])
    n = len(runs[0].start) if runs else 0
    if not P0 or sum(len(p) for p in P0) < 3 * (n + 1):
        m = sum(len(p) for p in P0)
        return RunningMapFit("failed", f"{m} pairs of landing states: at least {3 * (n + 1)} "
                             "are needed to fit the stride map", [], [], math.nan, math.nan,
                             math.nan, m)
    X0, X1 = np.vstack(P0), np.vstack(P1)
    Phi = np.column_stack([np.ones(len(X0)), X0])
    coef = np.linalg.lstsq(Phi, X1, rcond=None)[0]
    Lam = coef[1:].T
    res = X1 - Phi @ coef
    spread = X1.std(axis=0)
    rel = float(np.max(np.sqrt(np.mean(res ** 2, axis=0)) / np.where(spread > 0, spread,
                                                                       np.inf)))
    ev = np.linalg.eigvals(Lam)
    ev = ev[np.argsort(-np.abs(ev))]
    rng = np.random.default_rng(seed)
    mx = []
    for _ in range(200):
        i = rng.integers(0, len(X0), len(X0))
        cf = np.linalg.lstsq(Phi[i], X1[i], rcond=None)[0]
        mx.append(np.max(np.abs(np.linalg.eigvals(cf[1:].T))))
    top = float(np.abs(ev[0]))
    return RunningMapFit(
        "ok", f"MuJoCo's stride map from {len(X0)} pairs: max |lambda| {top:.3g} +- "
              f"{np.std(mx):.2g}, relative residual {rel:.2g}",
        Lam.tolist(), [complex(e) for e in ev], top, float(np.std(mx)), rel, int(len(X0)))


class RunningLoop:
    """The running controller in MuJoCo, built once and run many times (module docstring).

    Parameters
    ----------
    controller : RunningController
        The law, its gait and robot.
    settings : ContactSettings
        MuJoCo's time step, contact, feet and friction (default :data:`STIFF`).
    fixed_point : array_like, optional
        x*, the stance state at landing the deviations are measured from (default the
        gait's first stance state, the collocated one).
    max_slip : float
        Slip of the stance foot in a stance that ends the run, m.
    time_limits : float
        A phase lasting more than this many times the gait's ends the run.
    min_stance : float
        Before this fraction of the gait's stance the stance foot leaving the floor is a
        bounce off the landing, not a takeoff.
    stop_on_saturation : bool
        End the run at the first commanded torque beyond the limit (otherwise MuJoCo clips
        it and the time clipped is recorded).
    torque_limit : float, optional
        The motors' limit, N m (default the controller's).
    liftoff_time : float
        The stance foot's force must stay zero this long for a takeoff, s; the takeoff is
        dated at its first zero.  At stiff contact (solref two time steps) the loaded foot
        chatters: its contact drops for single time steps all along the stance.
    liftoff_height : float
        ... and its sphere must be this far above the floor, m (the chatter lifts it by
        hundredths of a millimetre).

    Raises
    ------
    ValueError
        Naming the argument.
    """

    def __init__(self, controller: RunningController, settings: ContactSettings = STIFF,
                 fixed_point=None, max_slip: float = 0.05, time_limits: float = 2.0,
                 min_stance: float = 0.25, stop_on_saturation: bool = False,
                 torque_limit: float | None = None, liftoff_time: float = 0.006,
                 liftoff_height: float = 1e-4):
        if not isinstance(controller, RunningController):
            raise ValueError("controller: a RunningController is needed "
                             f"(biped_casadi.control.running), got {type(controller).__name__}")
        if not isinstance(settings, ContactSettings):
            raise ValueError(f"settings must be ContactSettings, got {type(settings).__name__}")
        for name, v in (("max_slip", max_slip), ("time_limits", time_limits),
                        ("liftoff_time", liftoff_time), ("liftoff_height", liftoff_height)):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
                    or not v > 0:
                raise ValueError(f"{name} must be a positive number, got {v!r}")
        if time_limits <= 1:
            raise ValueError(f"time_limits must be above 1, got {time_limits!r}")
        if isinstance(min_stance, bool) or not isinstance(min_stance, (int, float)) \
                or not 0 <= min_stance < 1:
            raise ValueError(f"min_stance must be a fraction in [0, 1), got {min_stance!r}")
        mujoco = _mujoco()
        c = self.controller = controller
        self.model = model = c.model
        self.gait = g = c.gait
        self.settings = settings
        self.max_slip, self.time_limits = float(max_slip), float(time_limits)
        self.min_stance, self.stop_on_saturation = float(min_stance), bool(stop_on_saturation)
        self.liftoff_time, self.liftoff_height = float(liftoff_time), float(liftoff_height)
        self.torque_limit = torque_limit_of(model.description,
                                            c.torque_limit if torque_limit is None
                                            else torque_limit)
        try:
            self.m = mujoco.MjModel.from_xml_string(mjcf(model, settings, self.torque_limit))
        except ValueError as e:
            raise ValueError(f"settings: MuJoCo rejects the model: {str(e).splitlines()[0]}") \
                from None
        self.d = mujoco.MjData(self.m)
        self.layout = layout(model)
        self.feet = tuple(mujoco.mj_name2id(self.m, mujoco.mjtObj.mjOBJ_GEOM, f"foot_{leg}")
                          for leg in "ab")
        self.fl = flight_model(model)
        self._stance_law = FastCall(c.stance_law)
        self._flight_law = FastCall(c.flight_law)
        self._landing = FastCall(self.fl.landing_swing)
        self.T_stance, self.T_flight = float(g.T_stance), float(g.T_flight)
        self.step_length = float(g.step_length)
        nq = model.nq
        x0 = np.asarray(g.x_stance, float)[:, 0]
        xs = x0 if fixed_point is None else np.asarray(fixed_point, float).ravel()
        if xs.shape != (2 * nq,) or not np.all(np.isfinite(xs)):
            raise ValueError(f"fixed_point must be {2 * nq} finite numbers (q, dq), got "
                             f"{np.asarray(fixed_point).shape}")
        self.x_star = xs
        self.fall_height = 0.5625 * model.description.leg_length
        self.upright = float(model.description.torso_upright)

    def gait_record(self) -> dict:
        """The gait's figures a run is measured against.

        Returns
        -------
        dict
            ``T_stance``, ``T_flight`` (s), ``speed`` (m/s), ``step_length`` (m).
        """
        return dict(T_stance=self.T_stance, T_flight=self.T_flight,
                    speed=self.step_length / (self.T_stance + self.T_flight),
                    step_length=self.step_length)

    def controller_record(self) -> dict:
        """The controller's law and gains.

        Returns
        -------
        dict
            ``law``, ``Kp``, ``Kd``, ``M1``, ``saturate``.
        """
        c = self.controller
        return dict(law=c.law, Kp=c.Kp.tolist(), Kd=c.Kd.tolist(), M1=c.M1.tolist(),
                    saturate=c.saturate)

    def at(self, **changes) -> "RunningLoop":
        """The same loop with some MuJoCo settings changed (``timestep``, ``solref``, ...).

        Parameters
        ----------
        **changes
            Fields of :class:`~biped_casadi.mujoco.mjcf.ContactSettings` to change.

        Returns
        -------
        RunningLoop
        """
        import dataclasses
        return RunningLoop(self.controller, dataclasses.replace(self.settings, **changes),
                           self.x_star, self.max_slip, self.time_limits, self.min_stance,
                           self.stop_on_saturation, self.torque_limit, self.liftoff_time,
                           self.liftoff_height)

    def _foot(self, qpos, qvel, leg):
        """World (x, z) of leg ``leg``'s point foot and its velocity."""
        lay = self.layout
        i = 3 + leg * lay.k
        phi = qpos[2] + np.cumsum(qpos[i:i + lay.k])
        dphi = qvel[2] + np.cumsum(qvel[i:i + lay.k])
        L = np.asarray(lay.lengths)
        s, c = np.sin(phi), np.cos(phi)
        p = qpos[:2] - np.array([np.sum(L * s), np.sum(L * c)])
        v = qvel[:2] - np.array([np.sum(L * c * dphi), -np.sum(L * s * dphi)])
        return p, v

    def _extended(self, qpos, qvel, leg, origin):
        """The flight state (qe, dqe) with leg ``leg`` as the one that last stood."""
        A = self.layout.A[leg]
        p, v = self._foot(qpos, qvel, leg)
        return (np.r_[A @ qpos[2:], p - origin], np.r_[A @ qvel[2:], v])

    def _fz(self, leg) -> tuple:
        """(touching, normal force) of a foot in MuJoCo's contacts (of the state the last
        step started from)."""
        d = self.d
        if not d.ncon:
            return False, 0.0
        mujoco = _mujoco()
        f = self.feet[leg]
        touch, fz, out = False, 0.0, np.zeros(6)
        for i in range(d.ncon):
            g = d.contact.geom[i]
            if g[0] == f or g[1] == f:
                touch = True
                mujoco.mj_contactForce(self.m, d, i, out)
                fz += out[0]
        return touch, fz

    def initial_state(self, x) -> tuple:
        """MuJoCo's (qpos, qvel) of a stance state: leg a on the floor at x = 0, at rest.

        Parameters
        ----------
        x : array_like
            (2 nq,) the toolkit's (q, dq), rad and rad/s.

        Returns
        -------
        tuple of numpy.ndarray
        """
        nq = self.model.nq
        return self.layout.from_toolkit(x[:nq], x[nq:], 0, foot=(0.0, self.settings.foot_radius))

    def run(self, start=None, strides: int = 30, log: bool = False) -> MujocoRun:
        """Run ``strides`` strides from a stance state at landing.

        Parameters
        ----------
        start : array_like, optional
            (q, dq) just after a landing (default the loop's fixed point).
        strides : int
            Landings to reach.
        log : bool
            Keep every MuJoCo state.

        Returns
        -------
        MujocoRun
        """
        if isinstance(strides, bool) or not isinstance(strides, (int, np.integer)) \
                or strides < 1:
            raise ValueError(f"strides must be a positive integer, got {strides!r}")
        nq = self.model.nq
        x0 = self.x_star.copy() if start is None else np.asarray(start, float).ravel()
        if x0.shape != (2 * nq,) or not np.all(np.isfinite(x0)):
            raise ValueError(f"start must be {2 * nq} finite numbers (q, dq), got "
                             f"{np.asarray(start).shape}")
        mujoco = _mujoco()
        m, d, lay = self.m, self.d, self.layout
        mujoco.mj_resetData(m, d)
        d.qpos[:], d.qvel[:] = self.initial_state(x0)
        mujoco.mj_forward(m, d)
        dt, r, U = float(m.opt.timestep), self.settings.foot_radius, self.torque_limit
        xs = self.x_star
        records, devs = [], [float(np.max(np.abs(x0 - xs)))]
        logs = ([], [], [], [], []) if log else None
        status, message = "ran", ""
        leg, phase = 0, 0                  # stance leg (0: a), phase (0 stance, 1 flight)
        k, t0 = 0, 0.0                     # MuJoCo steps, the phase's start time
        t_land, stance_T = 0.0, math.nan
        x_land = float(d.geom_xpos[self.feet[0], 0])
        origin = np.zeros(2)               # the pushing foot's point at takeoff
        peak = slip = fz_max = 0.0
        clipped, loaded, off, bounce = 0, False, None, 0
        x_prev, phi_prev = x_land, float(x0[0])
        prev = self._prev2 = (d.qpos.copy(), d.qvel.copy())
        kmax = [self.time_limits * self.T_stance, self.time_limits * self.T_flight]
        t_wall = time.perf_counter()
        while status == "ran" and len(records) < strides:
            t = k * dt
            qpos, qvel = d.qpos, d.qvel
            A = lay.A[leg]
            if phase == 0:
                u = self._stance_law(A @ qpos[2:], A @ qvel[2:], t - t0)[0].ravel()
            else:
                qe, dqe = self._extended(qpos, qvel, leg, origin)
                u = self._flight_law(qe, dqe, t - t0)[0].ravel()
            if not np.all(np.isfinite(u)):
                status, message = "diverged", f"stride {len(records) + 1}: the torque is not finite"
                break
            umax = float(np.max(np.abs(u)))
            peak = max(peak, umax)
            if umax > U:
                clipped += 1
                if self.stop_on_saturation:
                    status, message = "saturated", (
                        f"stride {len(records) + 1}: {umax:.1f} N m commanded (limit {U:g}) "
                        f"at {t - t0:.4f} s into the {('stance', 'flight')[phase]}")
                    break
            d.ctrl[:] = lay.G[leg] @ u
            if log:
                for a, v in zip(logs, (t, qpos.copy(), qvel.copy(), phase, leg)):
                    a.append(v)
            prev = (qpos.copy(), qvel.copy())
            mujoco.mj_step(m, d)
            k += 1
            # ---- the contacts of the state the step started from (time t)
            st_touch, fz = self._fz(leg)
            sw_touch, _ = self._fz(1 - leg)
            n = len(records) + 1
            qp = d.qpos
            if not np.all(np.isfinite(qp)):
                status, message = "diverged", f"stride {n}: MuJoCo's state is not finite"
                break
            lean = qp[2] if self.upright == 0.0 else float(torso_lean(qp[2], self.upright))
            if not (qp[1] - r > self.fall_height and -_HALF_PI < lean < _HALF_PI):
                status, message = "fell", (f"stride {n}: fell at t = {k * dt:.4g} s (hip "
                                           f"{qp[1] - r:.3g} m above the feet' level, torso "
                                           f"{qp[2]:.3g} rad)")
                break
            if phase == 0:
                fz_max = max(fz_max, fz)
                xf = float(d.geom_xpos[self.feet[leg], 0])      # of the state at t
                phi = float((lay.A[leg] @ prev[0][2:])[0])
                if st_touch:
                    slip += (xf - x_prev) - r * (phi - phi_prev)
                x_prev, phi_prev = xf, phi
                if abs(slip) > self.max_slip:
                    status, message = "slipped", (f"stride {n}: the stance foot slid "
                                                  f"{slip:.3g} m (more than {self.max_slip:g} m)")
                    break
                if sw_touch:
                    status, message = "double_contact", (
                        f"stride {n}: the swing foot touched the floor in stance at "
                        f"{t - t0:.4f} s")
                    break
                if fz > 0.0:
                    loaded, off = True, None
                elif loaded and off is None:
                    off = (t, self._foot(prev[0], prev[1], leg)[0])
                if off is not None and t - off[0] >= self.liftoff_time - 1e-12 \
                        and d.geom_xpos[self.feet[leg], 2] > r + self.liftoff_height:
                    if off[0] - t0 < self.min_stance * self.T_stance:
                        bounce += 1              # off the floor early: a bounce, not a takeoff
                    else:
                        stance_T, phase, t0, loaded = off[0] - t_land, 1, off[0], False
                        origin, off = off[1], None
                        self._prev2 = prev
                        continue
            else:
                if st_touch:
                    status, message = "double_contact", (
                        f"stride {n}: the foot that pushed off touched the floor again "
                        f"{t - t0:.4f} s into the flight")
                    break
                if sw_touch:
                    # the touchdown, interpolated to where the sphere meets the floor
                    q_a, v_a = self._prev2
                    q_b, v_b = prev
                    z_a = self._foot(q_a, v_a, 1 - leg)[0][1]
                    z_b = self._foot(q_b, v_b, 1 - leg)[0][1]
                    w = 1.0 if z_a <= z_b else min(max((z_a - r) / (z_a - z_b), 0.0), 1.0)
                    qpos_td, qvel_td = q_a + w * (q_b - q_a), v_a + w * (v_b - v_a)
                    t_td = t - (1.0 - w) * dt
                    qe, dqe = self._extended(qpos_td, qvel_td, leg, origin)
                    qp_, dqp_ = self._landing(qe, dqe)[:2]
                    x_next = np.r_[qp_.ravel(), dqp_.ravel()]
                    foot_td = self._foot(qpos_td, qvel_td, 1 - leg)[0][0]
                    length = foot_td - x_land
                    dev = float(np.max(np.abs(x_next - xs)))
                    devs.append(dev)
                    records.append(RunningStride(
                        index=len(records), t_landing=t_land, stance=stance_T,
                        flight=t_td - t0, step_length=float(length),
                        speed=float(length / (t_td - t_land)), landing_state=x_next.tolist(),
                        deviation=dev, peak_torque=peak, clipped_time=clipped * dt,
                        slip=float(slip), fz_max=float(fz_max), bounce_time=bounce * dt))
                    leg, phase, t0, t_land, x_land = 1 - leg, 0, t_td, t_td, foot_td
                    peak = slip = fz_max = 0.0
                    clipped, loaded, bounce = 0, False, 0
                    x_prev = float(d.geom_xpos[self.feet[leg], 0])
                    phi_prev = float((lay.A[leg] @ prev[0][2:])[0])
                    self._prev2 = prev
                    continue
            self._prev2 = prev
            if t + dt - t0 > kmax[phase]:
                status, message = "phase_too_long", (
                    f"stride {n}: the {('stance', 'flight')[phase]} lasted more than "
                    f"{self.time_limits:g} times the gait's "
                    f"({kmax[phase] / self.time_limits:.4f} s)")
        wall = time.perf_counter() - t_wall
        if status == "ran":
            message = (f"{len(records)} strides, deviation from x* {devs[0]:.2e} -> "
                       f"{devs[-1]:.2e}")
        arrays = {}
        if log:
            arrays = dict(t=np.array(logs[0]), qpos=np.array(logs[1]), qvel=np.array(logs[2]),
                          phase=np.array(logs[3], np.int8), stance_leg=np.array(logs[4], np.int8))
        return MujocoRun(status=status, message=message, n_strides=int(strides),
                         strides=records, start=x0.tolist(), fixed_point=xs.tolist(),
                         deviations=devs, gait=self.gait_record(),
                         controller=self.controller_record(), settings=self.settings.to_dict(),
                         torque_limit=self.torque_limit, mujoco_steps=k, wall_time=wall,
                         **arrays)


def run_in_mujoco(controller: RunningController, start=None, strides: int = 30,
                  settings: ContactSettings = STIFF, fixed_point=None, log: bool = False,
                  **options) -> MujocoRun:
    """Run a running controller in MuJoCo (module docstring).

    Parameters
    ----------
    controller : RunningController
        The law on its gait.
    start : array_like, optional
        The stance state at landing to start from (default ``fixed_point``).
    strides : int
        Landings to reach.
    settings : ContactSettings
        MuJoCo's settings (default :data:`~biped_casadi.mujoco.STIFF`).
    fixed_point : array_like, optional
        x* (``running_stability(running_cycle(controller)).fixed_point``); default the
        gait's collocated first stance state.
    log : bool
        Keep every MuJoCo state.
    **options
        Of :class:`RunningLoop` (``max_slip``, ``time_limits``, ``min_stance``,
        ``stop_on_saturation``, ``torque_limit``, ``liftoff_time``).

    Returns
    -------
    MujocoRun
    """
    loop = RunningLoop(controller, settings, fixed_point, **options)
    return loop.run(start, strides, log)
