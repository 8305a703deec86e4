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
  ``liftoff_height`` above the floor.  At stiff contact the loaded foot chatters (its
  contact drops for single time steps all along the stance, more often as the force
  falls), hence the confirmation; a loss of contact before ``min_stance`` of the gait's
  stance is a bounce off the landing (recorded as ``bounce_time``), not a takeoff.
  The flight clock (``takeoff_clock``) starts, by default ('guard'), where the rigid
  model's takeoff guard (``takeoff_guard``: the normal force the stance foot would need,
  at MuJoCo's state and the torques applied) last crossed zero going down, interpolated
  between time steps: the exact map's own event.  MuJoCo's first zero-force state
  ('contact', the earlier rule; used too when the guard has not crossed by the
  confirmation) scatters by a few ms stride to stride with the chatter (std 2.7 ms at
  dt 1 ms, 4.9 ms at 2 ms against the guard over 300 strides), and the flight law's
  time-based reference turns that scatter into most of the landing states' jitter;
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

import numpy as np

from ..control.running import FLIGHT_CLOCKS, RunningController
from ..model import flight_model
from ..model.description import torso_lean
from ..numerics import FastCall
from .mjcf import STIFF, ContactSettings, layout, mjcf, torque_limit_of
from .running_records import (MujocoRun, RunningMapFit, RunningStride, decay_rate,
                              fit_running_map)

__all__ = ["RUN_OUTCOMES", "TAKEOFF_CLOCKS", "RunningLoop", "MujocoRun", "RunningStride", "run_in_mujoco",
           "decay_rate", "fit_running_map", "RunningMapFit"]

#: where the flight clock starts (module docstring, :class:`RunningLoop`)
TAKEOFF_CLOCKS = ("guard", "contact")
#: how a run ends: 'ran', or the reason it stopped (module docstring)
RUN_OUTCOMES = ("ran", "fell", "slipped", "phase_too_long", "double_contact", "saturated",
                "diverged")
_HALF_PI = math.pi / 2


def _mujoco():
    import mujoco
    return mujoco


def _applied_law(c: RunningController, phase: str) -> FastCall:
    """The controller's law of a phase as the robot receives it: clipped at its limit when
    it saturates, as its C export's torques are.

    Parameters
    ----------
    c : RunningController
        The controller.
    phase : {'stance', 'flight'}
        The phase.

    Returns
    -------
    FastCall
        ``u(q, dq, t)`` as a list holding the (nu, 1) torques.
    """
    law = getattr(c, f"{phase}_law")
    return FastCall(c.applied_law(phase) if c.saturate else law)


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
    torque_limit : float or tuple of float, optional
        The motors' limit, N m, or one per torque u1 .. u_nu (the same for a joint on both
        legs); default the controller's (the robot's: each joint's own where its joints'
        limits differ).
    liftoff_time : float
        The stance foot's force must stay zero this long for a takeoff, s; the takeoff is
        dated at its first zero.  At stiff contact (solref two time steps) the loaded foot
        chatters: its contact drops for single time steps all along the stance.
    liftoff_height : float
        ... and its sphere must be this far above the floor, m (the chatter lifts it by
        hundredths of a millimetre).
    takeoff_clock : str
        Where the flight clock starts (module docstring): 'guard' (the rigid model's
        takeoff guard on MuJoCo's states, the default) or 'contact' (MuJoCo's first
        zero-force state).
    flight_clock : str
        The flight law's clock (:data:`~biped_casadi.control.running.FLIGHT_CLOCKS`):
        'takeoff' (the time since the takeoff dated by ``takeoff_clock``, the default) or
        'stride' (the time since landing less the gait's stance, as the exact map's
        ``running_cycle(..., flight_clock='stride')``).
    compiled : CompiledRunningLaw, optional
        The controller's law from its C export
        (:class:`~biped_casadi.control.compiled_running.CompiledRunningLaw`), called
        instead of its CasADi Functions (default None: the Functions).  Either way a
        saturating controller's torques are clipped at its limit before the loop sees
        them (``stop_on_saturation`` then never stops the run).

    Raises
    ------
    ValueError
        Naming the argument.
    """

    def __init__(self, controller: RunningController, settings: ContactSettings = STIFF,
                 fixed_point=None, max_slip: float = 0.05, time_limits: float = 2.0,
                 min_stance: float = 0.25, stop_on_saturation: bool = False,
                 torque_limit: float | None = None, liftoff_time: float = 0.006,
                 liftoff_height: float = 1e-4, takeoff_clock: str = "guard",
                 compiled=None, flight_clock: str = "takeoff"):
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
        if takeoff_clock not in TAKEOFF_CLOCKS:
            raise ValueError(f"takeoff_clock must be one of {', '.join(TAKEOFF_CLOCKS)}, got "
                             f"{takeoff_clock!r}")
        if flight_clock not in FLIGHT_CLOCKS:
            raise ValueError(f"flight_clock must be one of {', '.join(FLIGHT_CLOCKS)}, got "
                             f"{flight_clock!r}")
        if compiled is not None and not (callable(getattr(compiled, "stance", None))
                                         and callable(getattr(compiled, "flight", None))):
            raise ValueError("compiled: a CompiledRunningLaw is needed "
                             f"(biped_casadi.control.compiled_running), got "
                             f"{type(compiled).__name__}")
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
        self.takeoff_clock, self.flight_clock = takeoff_clock, flight_clock
        self.torque_limit = torque_limit_of(model.description,
                                            c.torque_limit if torque_limit is None
                                            else torque_limit)
        text = mjcf(model, settings, self.torque_limit)        # our checks: as they are
        try:
            self.m = mujoco.MjModel.from_xml_string(text)
        except ValueError as e:
            raise ValueError(f"settings: MuJoCo rejects the model: {str(e).splitlines()[0]}") \
                from None
        self.d = mujoco.MjData(self.m)
        self.layout = layout(model)
        self.feet = tuple(mujoco.mj_name2id(self.m, mujoco.mjtObj.mjOBJ_GEOM, f"foot_{leg}")
                          for leg in "ab")
        self.fl = flight_model(model)
        self.compiled = compiled
        self._stance_law = _applied_law(c, "stance") if compiled is None else compiled.stance
        self._flight_law = _applied_law(c, "flight") if compiled is None else compiled.flight
        self._landing = FastCall(self.fl.landing_swing)
        self._guard = FastCall(self.fl.takeoff_guard)
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
            ``law``, ``Kp``, ``Kd``, ``M1``, ``saturate``; ``compiled`` (the library's
            ``describe()``) when the law is the compiled one.
        """
        c = self.controller
        rec = dict(law=c.law, Kp=c.Kp.tolist(), Kd=c.Kd.tolist(), M1=c.M1.tolist(),
                   saturate=c.saturate)
        if self.compiled is not None:
            describe = getattr(self.compiled, "describe", None)
            rec["compiled"] = describe() if callable(describe) else type(self.compiled).__name__
        return rec

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
                           self.liftoff_height, self.takeoff_clock, self.compiled,
                           self.flight_clock)

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
        m, d = self.m, self.d
        mujoco.mj_resetData(m, d)
        d.qpos[:], d.qvel[:] = self.initial_state(x0)
        mujoco.mj_forward(m, d)
        run = _Run(self, x0, log)
        t_wall = time.perf_counter()
        while run.status == "ran" and len(run.records) < strides:
            if not run.control():
                break
            mujoco.mj_step(m, d)
            run.k += 1
            run.advance()
        wall = time.perf_counter() - t_wall
        devs = run.devs
        if run.status == "ran":
            run.message = (f"{len(run.records)} strides, deviation from x* {devs[0]:.2e} -> "
                           f"{devs[-1]:.2e}")
        arrays = {}
        if log:
            lg = run.logs
            arrays = dict(t=np.array(lg[0]), qpos=np.array(lg[1]), qvel=np.array(lg[2]),
                          phase=np.array(lg[3], np.int8), stance_leg=np.array(lg[4], np.int8))
        return MujocoRun(status=run.status, message=run.message, n_strides=int(strides),
                         strides=run.records, start=x0.tolist(),
                         fixed_point=self.x_star.tolist(), deviations=devs,
                         gait=self.gait_record(), controller=self.controller_record(),
                         settings=self.settings.to_dict(), torque_limit=self.torque_limit,
                         mujoco_steps=run.k, wall_time=wall, **arrays)


class _Run:
    """The bookkeeping of one run: the phase, its clock and the stance foot's contact,
    the records (one MuJoCo step at a time: :meth:`control` before it, :meth:`advance`
    after, which reads the contacts of the state the step started from)."""

    def __init__(self, loop: RunningLoop, x0, log: bool):
        self.loop, self.d, self.lay = loop, loop.d, loop.layout
        self.dt = float(loop.m.opt.timestep)
        self.r, self.U = loop.settings.foot_radius, loop.torque_limit
        #: the motors' limits as an array: one number, or per torque u1 .. u_nu
        self.Ua = np.asarray(self.U, float)
        self.records, self.devs = [], [float(np.max(np.abs(x0 - loop.x_star)))]
        self.logs = ([], [], [], [], []) if log else None
        self.status, self.message = "ran", ""
        self.leg, self.phase = 0, 0            # stance leg (0: a), phase (0 stance, 1 flight)
        self.k, self.t0 = 0, 0.0               # MuJoCo steps, the phase's start time
        self.t_land, self.stance_T = 0.0, math.nan
        self.x_land = float(self.d.geom_xpos[loop.feet[0], 0])
        self.origin = np.zeros(2)              # the pushing foot's point at takeoff
        self.x_prev, self.phi_prev = self.x_land, float(x0[0])
        self.prev = self.prev2 = (self.d.qpos.copy(), self.d.qvel.copy())
        self.kmax = (loop.time_limits * loop.T_stance, loop.time_limits * loop.T_flight)
        self._new_stride()

    def _new_stride(self):
        self.peak = self.slip = self.fz_max = 0.0
        self.clipped, self.bounce, self.loaded, self.off = 0, 0, False, None
        self.g_prev = self.t_guard = None
        self.guard_gap = math.nan

    def stop(self, status: str, message: str):
        """End the run in stride ``len(records) + 1``."""
        self.status = status
        self.message = f"stride {len(self.records) + 1}: {message}"

    def control(self) -> bool:
        """The law's torques at MuJoCo's state into ``ctrl``; False when the run stops."""
        loop, d, lay = self.loop, self.d, self.lay
        t = self.k * self.dt
        qpos, qvel, A = d.qpos, d.qvel, lay.A[self.leg]
        if self.phase == 0:
            u = loop._stance_law(A @ qpos[2:], A @ qvel[2:], t - self.t0)[0].ravel()
        else:
            qe, dqe = loop._extended(qpos, qvel, self.leg, self.origin)
            origin = self.t0 if loop.flight_clock == "takeoff" else self.t_land + loop.T_stance
            u = loop._flight_law(qe, dqe, t - origin)[0].ravel()
        if not np.all(np.isfinite(u)):
            self.stop("diverged", "the torque is not finite")
            return False
        umax = float(np.max(np.abs(u)))
        self.peak = max(self.peak, umax)
        over = np.abs(u) - self.Ua                         # each torque against its motor's
        if np.any(over > 0):
            self.clipped += 1
            if loop.stop_on_saturation:
                i = int(np.argmax(over))
                said = f"{umax:.1f} N m commanded (limit {self.U:g})" if self.Ua.ndim == 0 \
                    else f"|u{i + 1}| = {abs(u[i]):.1f} N m commanded (its limit {self.U[i]:g})"
                self.stop("saturated", f"{said} at {t - self.t0:.4f} s into the "
                                       f"{('stance', 'flight')[self.phase]}")
                return False
        d.ctrl[:] = lay.G[self.leg] @ u
        self.u_applied = np.clip(u, -self.Ua, self.Ua)     # what MuJoCo's motors apply
        if self.logs is not None:
            for a, v in zip(self.logs, (t, qpos.copy(), qvel.copy(), self.phase, self.leg)):
                a.append(v)
        self.prev2, self.prev = self.prev, (qpos.copy(), qvel.copy())
        return True

    def advance(self):
        """After a MuJoCo step: a fall, then the phase's contacts (of the state at t)."""
        loop, d = self.loop, self.d
        t = (self.k - 1) * self.dt                  # the state the step started from
        qp = d.qpos
        if not np.all(np.isfinite(qp)):
            return self.stop("diverged", "MuJoCo's state is not finite")
        lean = qp[2] if loop.upright == 0.0 else float(torso_lean(qp[2], loop.upright))
        if not (qp[1] - self.r > loop.fall_height and -_HALF_PI < lean < _HALF_PI):
            return self.stop("fell", f"fell at t = {self.k * self.dt:.4g} s (hip "
                                     f"{qp[1] - self.r:.3g} m above the feet' level, torso "
                                     f"{qp[2]:.3g} rad)")
        st_touch, fz = loop._fz(self.leg)
        sw_touch = loop._fz(1 - self.leg)[0]
        if self.phase == 0:
            self._stance(t, st_touch, fz, sw_touch)
        elif st_touch:
            self.stop("double_contact", f"the foot that pushed off touched the floor again "
                                        f"{t - self.t0:.4f} s into the flight")
        elif sw_touch:
            return self._touchdown(t)
        if self.status == "ran" and t + self.dt - self.t0 > self.kmax[self.phase]:
            self.stop("phase_too_long", f"the {('stance', 'flight')[self.phase]} lasted more "
                                        f"than {loop.time_limits:g} times the gait's "
                                        f"({self.kmax[self.phase] / loop.time_limits:.4f} s)")
        return None

    def _stance(self, t, st_touch, fz, sw_touch):
        """Slip, a touch of the swing foot, the takeoff (confirmed, dated back)."""
        loop, prev, leg = self.loop, self.prev, self.leg
        self.fz_max = max(self.fz_max, fz)
        xf = float(self.d.geom_xpos[loop.feet[leg], 0])      # of the state at t
        phi = float((self.lay.A[leg] @ prev[0][2:])[0])
        if st_touch:
            self.slip += (xf - self.x_prev) - self.r * (phi - self.phi_prev)
        self.x_prev, self.phi_prev = xf, phi
        if abs(self.slip) > loop.max_slip:
            return self.stop("slipped", f"the stance foot slid {self.slip:.3g} m (more than "
                                        f"{loop.max_slip:g} m)")
        if sw_touch:
            return self.stop("double_contact", f"the swing foot touched the floor in stance "
                                               f"at {t - self.t0:.4f} s")
        if fz > 0.0:
            self.loaded, self.off = True, None
        elif self.loaded and self.off is None:
            self.off = (t, loop._foot(prev[0], prev[1], leg)[0])
        if loop.takeoff_clock == "guard":
            self._track_guard(t)
        if self.off is not None and t - self.off[0] >= loop.liftoff_time - 1e-12 \
                and self.d.geom_xpos[loop.feet[leg], 2] > self.r + loop.liftoff_height:
            if self.off[0] - self.t0 < loop.min_stance * loop.T_stance:
                self.bounce += 1                 # off the floor early: a bounce, not a takeoff
            else:
                t_off = self.off[0] if self.t_guard is None else self.t_guard
                if self.t_guard is not None:
                    self.guard_gap = self.t_guard - self.off[0]
                self.stance_T, self.phase, self.t0 = t_off - self.t_land, 1, t_off
                self.origin, self.off, self.loaded = self.off[1], None, False
        return None

    def _track_guard(self, t):
        """The rigid model's takeoff guard (the stance foot's normal force) at MuJoCo's
        state at t under the torques applied there: the time it last crossed zero going
        down, interpolated (None while it is positive)."""
        loop = self.loop
        if t - self.t0 < loop.min_stance * loop.T_stance:
            return
        A, (q, v) = self.lay.A[self.leg], self.prev
        g = float(np.ravel(loop._guard(A @ q[2:], A @ v[2:], self.u_applied)[0])[0])
        if g > 0.0:
            self.t_guard = None
        elif self.t_guard is None and self.g_prev is not None and self.g_prev > 0.0:
            self.t_guard = t - self.dt * (1.0 - self.g_prev / (self.g_prev - g))
        self.g_prev = g

    def _touchdown(self, t):
        """The swing foot's first contact, interpolated to where its sphere meets the
        floor: record the stride (the rigid landing map's state), relabel, restart."""
        loop, leg, r = self.loop, self.leg, self.r
        (q_a, v_a), (q_b, v_b) = self.prev2, self.prev
        z_a = loop._foot(q_a, v_a, 1 - leg)[0][1]
        z_b = loop._foot(q_b, v_b, 1 - leg)[0][1]
        w = 1.0 if z_a <= z_b else min(max((z_a - r) / (z_a - z_b), 0.0), 1.0)
        qpos_td, qvel_td = q_a + w * (q_b - q_a), v_a + w * (v_b - v_a)
        t_td = t - (1.0 - w) * self.dt
        qe, dqe = loop._extended(qpos_td, qvel_td, leg, self.origin)
        qp_, dqp_ = loop._landing(qe, dqe)[:2]
        x_next = np.r_[qp_.ravel(), dqp_.ravel()]
        foot_td = float(loop._foot(qpos_td, qvel_td, 1 - leg)[0][0])
        length = foot_td - self.x_land
        dev = float(np.max(np.abs(x_next - loop.x_star)))
        self.devs.append(dev)
        self.records.append(RunningStride(
            index=len(self.records), t_landing=self.t_land, stance=self.stance_T,
            flight=t_td - self.t0, step_length=length, speed=length / (t_td - self.t_land),
            landing_state=x_next.tolist(), deviation=dev, peak_torque=self.peak,
            clipped_time=self.clipped * self.dt, slip=float(self.slip),
            fz_max=float(self.fz_max), bounce_time=self.bounce * self.dt,
            takeoff_guard_gap=float(self.guard_gap)))
        self.leg, self.phase = 1 - leg, 0
        self.t0 = self.t_land = t_td
        self.x_land = foot_td
        self.x_prev = float(self.d.geom_xpos[loop.feet[self.leg], 0])
        self.phi_prev = float((self.lay.A[self.leg] @ q_b[2:])[0])
        self._new_stride()


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
        ``stop_on_saturation``, ``torque_limit``, ``liftoff_time``, ``takeoff_clock``,
        ``compiled``: the law of the controller's C export).

    Returns
    -------
    MujocoRun
    """
    loop = RunningLoop(controller, settings, fixed_point, **options)
    return loop.run(start, strides, log)
