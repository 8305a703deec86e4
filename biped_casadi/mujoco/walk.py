"""A design walking in MuJoCo: the closed loop of the exported law and MuJoCo's contacts.

Every MuJoCo step (time step dt) the law is called at MuJoCo's state, read in the
toolkit's coordinates with the current stance leg (:class:`~biped_casadi.mujoco.mjcf.
Layout`), and its torques are held over the step (MuJoCo's motors clip them at the
torque limit).  A step of the walk:

- starts at t = 0 from the gait's start (plus a perturbation), the stance foot's sphere
  on the ground at x = 0 and at rest, or at the previous touchdown;
- its old stance foot must lift off (lose its contact) before half the step; then the
  swing foot's first contact with the floor in front of the stance foot (beyond
  ``model.scuff_zone``) is the touchdown;
- MuJoCo's contact list after a step holds the contacts of the state it started from: the
  touchdown's state (q-, dq-) is the first state with the swing foot in contact, before
  any contact force has acted on it.  The next step's clock tau starts there, the legs
  are relabelled, and the law's step state is computed from the rigid impact map
  applied to (q-, dq-) (``step_start='impact'``, the default) or from MuJoCo's own state
  one time step later (``'contact'``; MuJoCo's soft impact has then barely begun: the
  virtual-constraint law's phase still runs backwards and the step cannot start).

MuJoCo's impact is not instantaneous: the walk never jumps the state; only the law's
step constants come from the rigid map.  For legs without knees
(``model.scuffing_ignored``) the swing foot's collisions are off while it passes the
stance foot, as the toolkit ignores that scuffing.

A walk ends 'walked' after its steps, or at the first of (:data:`OUTCOMES`): 'fell' (hip
below the model's fall height, torso past horizontal: leaning more than pi/2 from the
robot's ``torso_upright``), 'scuffed' (the old stance foot
still on the ground at half the step, or the swing foot touching down behind the stance
foot), 'slipped' (the stance foot's sphere sliding more than ``max_slip`` in a step:
its centre's travel less the rolling r dphi), 'no_impact' (no touchdown within
``horizon`` T), the law's own refusals ('singular', 'out_of_range': tau or the phase out
of the reference's range, or a step that cannot start) and 'diverged'.
"""
from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from ..control.design import Design
from ..control.output_law import SECTION
from ..control.reference import require_reference
from ..model.description import torso_lean
from ..numerics import FastCall
from ..simulation.perturbation import Perturbation
from . import cloop
from .law import LAWS, control_law
from .mjcf import STIFF, ContactSettings, layout, mjcf, torque_limit_of
from .records import MujocoStep, MujocoWalk, _Log, _pair

__all__ = ["OUTCOMES", "STEP_STARTS", "TOUCHDOWNS", "MujocoLoop", "walk", "mujoco_module",
           "SETTLE", "start_of"]

#: how a walk ends: 'walked', or the reason it stopped
OUTCOMES = ("walked", "fell", "scuffed", "slipped", "no_impact", "singular", "out_of_range",
            "diverged")
#: where each step's law state comes from: the rigid impact map at touchdown, or MuJoCo
STEP_STARTS = ("impact", "contact")
#: when a step's clock restarts and which state the impact map takes: MuJoCo's state at the
#: first contact (on the time grid), or the state interpolated to where the swing foot's
#: sphere meets the floor between that state and the one before
TOUCHDOWNS = ("grid", "interpolated")
#: the speed and period errors, and the worst pre-impact errors, are over the steps after
#: this many (the transient of a perturbation)
SETTLE = 10
_CODES = {1: "singular", 2: "out_of_range", 3: "diverged"}
_HALF_PI = math.pi / 2
_dot = np.dot


def mujoco_module():
    """The ``mujoco`` package, imported on first use.

    It is not needed to import the toolkit.

    Returns
    -------
    module
    """
    import mujoco
    return mujoco


class MujocoLoop:
    """The closed loop of one design in MuJoCo, built once and run many times.

    Holds the compiled MuJoCo model and its data, the law and the coordinate map (the
    caller owns it; runs reuse its buffers, one run at a time).

    Parameters
    ----------
    design : Design
        The design on its gait.
    settings : ContactSettings
        MuJoCo's time step, contact, feet and friction (default :data:`STIFF`).
    law : {'c', 'python'}
        The exported C law through ctypes, or the same law in Python.
    torque_limit : float, optional
        The motors' limit, N m (default the robot's; for a robot without one, the limit
        its gait was optimised for).
    step_start : {'impact', 'contact'}
        Where each step's law state comes from (module docstring).
    max_slip : float
        A stance foot sliding more than this in a step ends the walk ('slipped'), m.
    horizon : float
        A step without touchdown within ``horizon`` T ends the walk ('no_impact').
    touchdown : {'grid', 'interpolated'}
        The touchdown's time and state: MuJoCo's first state in contact, or interpolated
        between it and the state before to where the swing foot meets the floor (the
        clock and the impact map then do not carry the time grid's error).
    driver : {'auto', 'c', 'python'}
        Who runs the MuJoCo steps: a compiled C function, the Python loop falling back on
        the cases it does not handle (:mod:`~biped_casadi.mujoco.cloop`; 'auto', with the
        C law and a C compiler), the C function always ('c'), or the Python loop
        ('python').  The results are the same, bit for bit; the attribute ``driver`` says
        which runs.

    Raises
    ------
    ValueError
        Naming the argument: an unknown ``law``, ``step_start`` or ``driver``, settings
        MuJoCo rejects, a robot without a finite torque limit, a singular design,
        ``driver='c'`` where the C loop cannot run.
    """

    def __init__(self, design: Design, settings: ContactSettings = STIFF, law: str = "c",
                 torque_limit: float | None = None, step_start: str = "impact",
                 max_slip: float = 0.05, horizon: float = 2.0, touchdown: str = "grid",
                 driver: str = "auto"):
        if not isinstance(design, Design) or design.gait is None:
            raise ValueError("design: a Design on its gait is needed (Design.tv(gait, M1) "
                             "or Design.vc(gait))")
        if law not in LAWS:
            raise ValueError(f"law must be one of {', '.join(LAWS)}, got {law!r}")
        if touchdown not in TOUCHDOWNS:
            raise ValueError(f"touchdown must be one of {', '.join(TOUCHDOWNS)}, got "
                             f"{touchdown!r}")
        self.touchdown = touchdown
        if driver not in cloop.DRIVERS:
            raise ValueError(f"driver must be one of {', '.join(cloop.DRIVERS)}, got "
                             f"{driver!r}")
        if step_start not in STEP_STARTS:
            raise ValueError(f"step_start must be one of {', '.join(STEP_STARTS)}, got "
                             f"{step_start!r}")
        for name, v in (("max_slip", max_slip), ("horizon", horizon)):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not v > 0 \
                    or not math.isfinite(v):
                raise ValueError(f"{name} must be a positive number, got {v!r}")
        if not isinstance(settings, ContactSettings):
            raise ValueError(f"settings must be ContactSettings, got {type(settings).__name__}")
        mujoco = mujoco_module()
        self.design, self.settings, self.law_name = design, settings, law
        self.step_start_kind, self.max_slip, self.horizon = step_start, float(max_slip), \
            float(horizon)
        self.gait = g = design.gait
        self.model = model = g.model
        if torque_limit is None and not math.isfinite(model.description.torque_limit):
            # a robot without a limit (a URDF without efforts): the one its gait was made for
            torque_limit = getattr(getattr(g, "options", None), "torque_limit", None)
        self.torque_limit = torque_limit_of(model.description, torque_limit)
        text = mjcf(model, settings, self.torque_limit)        # our checks: as they are
        try:
            self.m = mujoco.MjModel.from_xml_string(text)
        except ValueError as e:
            raise ValueError(f"settings: MuJoCo rejects the model: {str(e).splitlines()[0]}") \
                from None
        self.d = mujoco.MjData(self.m)
        self.layout = layout(model)
        self.law = control_law(design, law)
        self._impact = FastCall(model.impact)
        self.feet = tuple(mujoco.mj_name2id(self.m, mujoco.mjtObj.mjOBJ_GEOM, f"foot_{leg}")
                          for leg in "ab")
        self.T = float(g.T)
        # the gait's speed and step length, evaluated once (each is a CasADi call)
        self.speed, self.step_length = float(g.speed), float(g.step_length)
        self.qu_T, self.dqu_T = float(g.q(self.T)[0]), float(g.dq(self.T)[0])
        self.fall_height = 0.5625 * model.description.leg_length
        ts = SECTION * self.T
        self.x_star = (float(g.q(ts)[0]), float(g.dq(ts)[0]))
        problem = cloop.c_driver_problem(self) if driver != "python" else "asked"
        if driver == "c" and problem:
            raise ValueError(f"driver: the steps cannot run in C: {problem}")
        self.driver = "python" if problem else "c"

    # -------------------------------------------------------------- helpers
    def at_timestep(self, timestep: float) -> "MujocoLoop":
        """The same loop at another MuJoCo time step.

        Its design, settings, law, torque limit, step start and touchdown kept.

        Parameters
        ----------
        timestep : float
            MuJoCo's time step, s.

        Returns
        -------
        MujocoLoop
        """
        return self.with_settings(timestep=timestep)

    def with_settings(self, **changes) -> "MujocoLoop":
        """The same loop with some MuJoCo settings changed (a time step, a contact).

        Its design, law, torque limit, step start and touchdown kept.

        Parameters
        ----------
        **changes
            Fields of :class:`~biped_casadi.mujoco.mjcf.ContactSettings` to change.

        Returns
        -------
        MujocoLoop
        """
        return MujocoLoop(self.design, dataclasses.replace(self.settings, **changes),
                          self.law_name, self.torque_limit, self.step_start_kind,
                          self.max_slip, self.horizon, self.touchdown)

    def gait_record(self) -> dict:
        """The gait's figures a walk is measured against.

        Returns
        -------
        dict
            ``T``, ``speed``, ``step_length``, ``qu_T``, ``dqu_T``.
        """
        return dict(T=self.T, speed=self.speed, step_length=self.step_length,
                    qu_T=self.qu_T, dqu_T=self.dqu_T)

    def initial_state(self, q0, dq0) -> tuple:
        """MuJoCo's (qpos, qvel) of a toolkit state: leg a on the ground at x = 0, at rest.

        Parameters
        ----------
        q0, dq0 : array_like
            The toolkit's state at the start of a step.

        Returns
        -------
        tuple of numpy.ndarray
        """
        return self.layout.from_toolkit(q0, dq0, 0, foot=(0.0, self.settings.foot_radius))

    # ------------------------------------------------------------------ run
    def run(self, q0, dq0, steps: int = 10, log: bool = False) -> MujocoWalk:
        """Walk ``steps`` steps from the toolkit state (q0, dq0) at the start of a step.

        Parameters
        ----------
        q0, dq0 : array_like
            The start (the gait's, perturbed), rad and rad/s.
        steps : int
            Touchdowns to reach.
        log : bool
            Keep every MuJoCo state (for figures and the animation).

        Returns
        -------
        MujocoWalk
        """
        if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 1:
            raise ValueError(f"steps must be a positive integer, got {steps!r}")
        mujoco = mujoco_module()
        m, d, nq = self.m, self.d, self.model.nq
        q0 = np.asarray(q0, float).reshape(nq)
        dq0 = np.asarray(dq0, float).reshape(nq)
        mujoco.mj_resetData(m, d)
        d.qpos[:], d.qvel[:] = self.initial_state(q0, dq0)
        mujoco.mj_forward(m, d)
        run = _Run(self, q0, dq0, int(steps), log)
        step, control, advance, records = mujoco.mj_step, run.control, run.advance, \
            run.records
        t0 = time.perf_counter()
        try:
            if self.driver == "c":
                self._run_c(run)
            else:
                while run.status == "walked" and len(records) < steps:
                    if not control():
                        break
                    step(m, d)
                    run.k += 1
                    advance()
        finally:
            if self.model.scuffing_ignored:
                for f in self.feet:
                    m.geom_contype[f] = 1
        return self._result(run, time.perf_counter() - t0)

    def _run_c(self, run):
        """The loop of :meth:`run` with the common steps in C: Python does a whole step,
        or the end of one, when the C function hands it back."""
        step, control, advance, records = mujoco_module().mj_step, run.control, \
            run.advance, run.records
        m, d, steps, driver = self.m, self.d, run.steps, cloop.Driver(run)
        while run.status == "walked" and len(records) < steps:
            event = driver(run)
            if event == cloop.PY_STEP:
                if not control():
                    break
                step(m, d)
                run.k += 1
                advance()
            elif event == cloop.PY_ADVANCE:
                advance()

    def _result(self, run, wall) -> MujocoWalk:
        records, steps, status = run.records, run.steps, run.status
        n = len(records)
        after = records[SETTLE:] if n > 2 * SETTLE else records
        if after:
            speed = sum(s.step_length for s in after) / sum(s.period for s in after)
            speed_err = speed / self.speed - 1.0
            period_err = float(np.mean([s.period for s in after])) / self.T - 1.0
        else:
            speed_err = period_err = math.nan
        late = records[SETTLE:]
        worst_q = max((abs(s.qu_error) for s in late), default=math.nan)
        worst_dq = max((abs(s.dqu_error) for s in late), default=math.nan)
        t, qpos, qvel, stance, u = run.log.arrays()
        return MujocoWalk(
            status=status, message=run.message, n_steps=steps, steps_walked=n,
            fail_step=run.fail_step if status != "walked" else steps, speed_error=speed_err,
            period_error=period_err, worst_qu_error=worst_q, worst_dqu_error=worst_dq,
            peak_commanded=max((s.peak_commanded for s in records), default=0.0),
            peak_applied=max((s.peak_applied for s in records), default=0.0),
            clipped_time=sum(s.clipped_time for s in records),
            max_slip=max((abs(s.slip) for s in records), default=0.0),
            max_penetration=max(0.0, float(run.r - run.z_min)),
            settings=self.settings.to_dict(), design=self.design.to_dict(), law=self.law_name,
            step_start=self.step_start_kind, touchdown=self.touchdown,
            torque_limit=self.torque_limit,
            gait=self.gait_record(), steps=records, mujoco_steps=int(run.k), wall_time=wall,
            t=t.copy(), qpos=qpos.copy(), qvel=qvel.copy(), stance=stance.copy(), u=u.copy())


class _Run:
    """The bookkeeping of one walk: the law's state, the step's clock and contacts, the
    records (one MuJoCo step at a time: :meth:`control` before it, :meth:`advance`
    after).

    The per-step work is Python's, about as long as MuJoCo's step itself, so it is kept
    lean without changing a bit of the result: MuJoCo's arrays are read through views
    taken once; q and dq are computed with the same BLAS product as ``A @ qpos[2:]``
    (not by indexing: A's first row adds three angles, in the order of BLAS's kernel),
    written in turn into two pairs of buffers (the previous state stays whole for the
    touchdown), on which the law is bound once (:meth:`~biped_casadi.control.compiled.
    NumericLaw.bind`: the compiled law is called through ctypes with no copies); the
    torques reach ``ctrl`` by the same product as ``G @ u``."""

    def __init__(self, loop: MujocoLoop, q0, dq0, steps: int, log: bool):
        self.loop, self.steps = loop, steps
        m, d = loop.m, loop.d
        self.m, self.d, self.feet = m, d, loop.feet
        # views on MuJoCo's arrays (fixed for the life of its data)
        self.qpos, self.qvel, self.ctrl, self.xpos = d.qpos, d.qvel, d.ctrl, d.geom_xpos
        self.angles, self.rates = d.qpos[2:], d.qvel[2:]
        nq, law = loop.model.nq, loop.law
        self.qs, self.dqs = (np.zeros(nq), np.zeros(nq)), (np.zeros(nq), np.zeros(nq))
        self.slot = 1                                   # the buffers of the last state
        self.p = np.zeros(law.n_par)                    # the law's step state
        self.calls = tuple(law.bind(q, dq, self.p) for q, dq in zip(self.qs, self.dqs))
        self.fall_height = loop.fall_height
        #: the torso's angle when upright (rad): falls are judged on the lean from it
        self.upright = float(loop.model.description.torso_upright)
        self.dt, self.T, self.U = float(m.opt.timestep), loop.T, loop.torque_limit
        #: per torque, its motor's limit where the joints' limits differ (else None)
        self.Us = None if np.ndim(self.U) == 0 else np.array(self.U, float)
        self.r = loop.settings.foot_radius
        self.A, self.G = loop.layout.A, loop.layout.G
        self.t_sec = SECTION * loop.T
        self.kmax = int(math.ceil(loop.horizon * loop.T / self.dt))
        self.ignore_scuff = loop.model.scuffing_ignored
        self.zone = loop.model.scuff_zone
        self.log = _Log(int(steps * 1.2 * loop.T / self.dt) + 16, m.nq, loop.model.nu, log)
        self.logging = log
        self.records, self.status, self.message = [], "walked", ""
        self.fail_step = steps
        self.stance, self.k, self.t0 = 0, 0, 0.0
        self.interpolate = loop.touchdown == "interpolated"
        self.q, self.dq = q0, dq0
        self.z_old, self.q_old, self.dq_old = math.inf, q0, dq0
        self.x_prev, self.phi_prev = float(d.geom_xpos[self.feet[0], 0]), float(q0[0])
        self.x_touch = self.x_prev
        #: the lowest height of either foot's centre over the walk (the feet's depth in
        #: the floor), m
        self.z_min = math.inf
        self._new_step()
        start = loop.law.step_start(q0, dq0)
        self.p[:] = start.p
        if start.problem:
            self.stop("out_of_range", f"step 1 cannot start: {start.problem}")

    def _new_step(self):
        self.lifted, self.liftoff = False, math.nan
        self.slip = self.travel = self.peak = self.peak_applied = 0.0
        self.airborne = self.clipped = 0
        self.section, self.qu_prev, self.dqu_prev = None, 0.0, 0.0

    def stop(self, status: str, message: str, step: int | None = None):
        """End the walk: ``step`` the 0-based index of the step that failed (default
        the step under way, the one after the last touchdown recorded)."""
        self.status, self.message = status, message
        self.fail_step = len(self.records) if step is None else step

    def control(self) -> bool:
        """The law's torques at MuJoCo's state into ``ctrl``; False when it refuses."""
        tau = self.k * self.dt - self.t0
        st = self.stance
        i = self.slot = 1 - self.slot                   # the buffers not holding q_old
        q, dq, As = self.qs[i], self.dqs[i], self.A[st]
        _dot(As, self.angles, out=q)                    # As @ qpos[2:], the same product
        _dot(As, self.rates, out=dq)
        self.q, self.dq = q, dq
        qu, dqu = q[0], dq[0]
        if self.section is None and tau >= self.t_sec:     # the Poincaré section 0.75 T
            w = (self.t_sec - tau + self.dt) / self.dt
            self.section = (self.qu_prev + w * (qu - self.qu_prev),
                            self.dqu_prev + w * (dqu - self.dqu_prev))
        self.qu_prev, self.dqu_prev = qu, dqu
        rc, u = self.calls[i](tau)
        if rc:
            status = _CODES.get(rc, "diverged")
            self.stop(status, f"step {len(self.records) + 1}: the law returned {rc} "
                              f"({status}) at tau = {tau:.4g} s")
            return False
        ul = u.tolist()                                 # finite: the law checks (code 3)
        umax = max(max(ul), -min(ul))                   # max |u_i|
        if umax > self.peak:
            self.peak = umax
        if self.Us is None:
            if umax > self.U:
                self.clipped += 1
        else:                                           # each torque against its motor's
            a = np.abs(u)
            self.clipped += bool(np.any(a > self.Us))
            self.peak_applied = max(self.peak_applied, float(np.max(np.minimum(a, self.Us))))
        _dot(self.G[st], u, out=self.ctrl)              # G @ u, the same product
        if self.logging:
            self.log.add(self.k * self.dt, self.qpos, self.qvel, st, u)
        return True

    def _touching(self):
        """Which feet touch the floor in MuJoCo's contacts (of the state the last step
        started from): (leg a's, leg b's)."""
        d = self.d
        if not d.ncon:
            return False, False
        geoms = d.contact.geom.ravel().tolist()         # (ncon, 2): both geoms of each
        return self.feet[0] in geoms, self.feet[1] in geoms

    def advance(self):
        """After a MuJoCo step: the stance foot's motion, a fall, the lift-off, the
        touchdown, the horizon."""
        xpos, feet, st = self.xpos, self.feet, self.stance
        sw = 1 - st
        touch = self._touching()
        z_now = xpos[feet[sw], 2]
        z_low = min(xpos[feet[0], 2], xpos[feet[1], 2])
        if z_low < self.z_min:
            self.z_min = z_low
        olds = (self.z_old, self.q_old, self.dq_old)
        self.z_old, self.q_old, self.dq_old = z_now, self.q, self.dq
        xs, phs = xpos[feet[st], 0], self.q[0]
        if touch[st] and self.lifted:                   # sliding in single support
            self.slip += (xs - self.x_prev) - self.r * (phs - self.phi_prev)
        else:                                           # the impact, or a bounce
            self.travel += xs - self.x_prev
            self.airborne += self.lifted
        self.x_prev, self.phi_prev = xs, phs
        qp = self.qpos
        lean = qp[2] if self.upright == 0.0 else float(torso_lean(qp[2], self.upright))
        if not (qp[1] - self.r > self.fall_height and -_HALF_PI < lean < _HALF_PI):
            n = len(self.records) + 1
            if not np.all(np.isfinite(qp)):
                return self.stop("diverged", f"step {n}: MuJoCo's state is not finite")
            return self.stop("fell", f"step {n}: fell at t = {self.k * self.dt:.4g} s (hip "
                                     f"{qp[1] - self.r:.3g} m above the feet' level, torso "
                                     f"{qp[2]:.3g} rad"
                             + ("" if self.upright == 0.0 else
                                f", {lean:.3g} rad from upright") + ")")
        if not self.lifted:
            tau = (self.k - 1) * self.dt - self.t0
            if not touch[sw]:
                self.lifted, self.liftoff = True, tau
                if self.ignore_scuff:
                    self.m.geom_contype[feet[sw]] = 0
            elif tau > 0.5 * self.T:
                self.stop("scuffed", f"step {len(self.records) + 1}: the old stance foot is "
                                     f"still on the ground at half the step (tau = {tau:.4g} s)")
        elif touch[sw] or (self.ignore_scuff and self.m.geom_contype[feet[sw]] == 0):
            x_sw, x_st = float(xpos[feet[sw], 0]), float(xpos[feet[st], 0])
            if self.ignore_scuff and self.m.geom_contype[feet[sw]] == 0 \
                    and x_sw - x_st > self.zone:
                self.m.geom_contype[feet[sw]] = 1
            if touch[sw]:
                if x_sw - x_st <= self.zone:
                    tau = (self.k - 1) * self.dt - self.t0
                    return self.stop("scuffed", f"step {len(self.records) + 1}: the swing foot "
                                                f"touched the ground {x_st - x_sw:.3g} m behind "
                                                f"the stance foot at tau = {tau:.4g} s")
                return self._touchdown(x_sw, x_st, z_now, olds)
        if self.status == "walked" and self.k * self.dt - self.t0 > self.kmax * self.dt:
            self.stop("no_impact", f"step {len(self.records) + 1}: no touchdown within "
                                   f"{self.loop.horizon:g} T")

    def _touchdown(self, x_sw, x_st, z_now, olds):
        """The touchdown at the state the last MuJoCo step started from (q, dq), or
        between it and the one before where the swing foot's sphere meets the floor
        (``touchdown='interpolated'``): record the step, relabel the legs, start the next
        step's law."""
        loop, q, dq = self.loop, self.q, self.dq
        t_td = (self.k - 1) * self.dt
        z_old, q_old, dq_old = olds
        if self.interpolate and z_old > z_now:
            w = min(max((z_old - self.r) / (z_old - z_now), 0.0), 1.0)
            q, dq = q_old + w * (q - q_old), dq_old + w * (dq - dq_old)
            t_td -= (1.0 - w) * self.dt
        tau = t_td - self.t0
        length = x_sw - self.x_touch
        speed = length / tau
        self.records.append(MujocoStep(
            index=len(self.records), t_start=self.t0, t_touchdown=t_td, period=tau, step_length=length, speed=speed,
            speed_error=speed / loop.speed - 1.0, period_error=tau / self.T - 1.0,
            qu_error=float(q[0]) - loop.qu_T, dqu_error=float(dq[0]) - loop.dqu_T,
            q_minus=q.tolist(), dq_minus=dq.tolist(), peak_commanded=float(self.peak),
            peak_applied=float(min(self.peak, self.U) if self.Us is None else self.peak_applied),
            clipped_time=self.clipped * self.dt,
            slip=float(self.slip), liftoff=self.liftoff, impact_travel=float(self.travel),
            airborne_time=self.airborne * self.dt, section=_pair(self.section),
            section_error=_pair(self.section, loop.x_star)))
        n = len(self.records)
        # a failure at the touchdown is the failure of the step it ends (index n - 1,
        # recorded), as in the Python simulator
        if abs(self.slip) > loop.max_slip:
            return self.stop("slipped", f"step {n}: the stance foot slid {self.slip:.3g} m "
                                        f"(more than {loop.max_slip:g} m)", n - 1)
        if not np.all(np.isfinite(self.d.qpos)):
            return self.stop("diverged", f"step {n}: MuJoCo's state is not finite", n - 1)
        self.x_touch, self.x_prev = x_sw, x_sw
        self.phi_prev = float(np.sum(q))            # the new stance leg's lowest link
        self.stance, self.t0 = 1 - self.stance, t_td
        if self.ignore_scuff:
            self.m.geom_contype[self.feet[self.stance]] = 1
        self._new_step()
        if n == self.steps:
            return None
        if loop.step_start_kind == "impact":
            qp, dqp = loop._impact(q, dq)
            start = loop.law.step_start(qp.ravel(), dqp.ravel())
        else:
            As = self.A[self.stance]
            start = loop.law.step_start(As @ self.d.qpos[2:], As @ self.d.qvel[2:])
        self.p[:] = start.p
        if start.problem:
            self.stop("out_of_range", f"step {n + 1} cannot start: {start.problem}")
        return None


def walk(design: Design, steps: int = 10, perturbation=None, settings: ContactSettings = STIFF,
         law: str = "c", step_start: str = "impact", torque_limit: float | None = None,
         max_slip: float = 0.05, horizon: float = 2.0, log: bool = False,
         touchdown: str = "grid") -> MujocoWalk:
    """Walk a design in MuJoCo (module docstring).

    Parameters
    ----------
    design : Design
        The design on its gait.
    steps : int
        Touchdowns to reach.
    perturbation : Perturbation or tuple, optional
        Added to the gait's start: a :class:`~biped_casadi.Perturbation`, or (q error, dq
        error) on every joint (rad, rad/s); default none.
    settings : ContactSettings
        Time step, contact, feet and friction (default :data:`~biped_casadi.mujoco.STIFF`).
    law : {'c', 'python'}
        The exported C law (compiled once and cached) or the same law in Python.
    step_start : {'impact', 'contact'}
        Each step's law state from the rigid impact map at touchdown, or from MuJoCo.
    torque_limit : float, optional
        The motors' limit, N m (default the robot's; for a robot without one, the limit
        its gait was optimised for).
    max_slip : float
        Slip of the stance foot in a step that ends the walk, m.
    horizon : float
        Steps longer than ``horizon`` T end the walk.
    log : bool
        Keep every MuJoCo state (``t``, ``qpos``, ``qvel``, ``stance``, ``u``).
    touchdown : {'grid', 'interpolated'}
        The touchdown's time and state (:class:`MujocoLoop`).

    Returns
    -------
    MujocoWalk

    Raises
    ------
    ValueError
        Naming the argument.
    """
    design = Design.require(design)
    loop = MujocoLoop(design, settings, law, torque_limit, step_start, max_slip, horizon,
                      touchdown)
    q0, dq0 = start_of(design.gait, perturbation)
    return loop.run(q0, dq0, steps, log)


def start_of(gait, perturbation=None) -> tuple:
    """The gait's start plus a perturbation.

    Parameters
    ----------
    gait : Reference
        The gait.
    perturbation : Perturbation, tuple of two floats, or None
        (q error, dq error) on every joint, or per joint as a Perturbation.

    Returns
    -------
    tuple of numpy.ndarray
        (q0, dq0).
    """
    nq = require_reference(gait).model.nq
    if perturbation is None:
        return np.array(gait.q(0.0), float), np.array(gait.dq(0.0), float)
    if not isinstance(perturbation, Perturbation):
        try:
            a, b = perturbation
        except (TypeError, ValueError):
            raise ValueError("perturbation must be a Perturbation or (q error, dq error), got "
                             f"{perturbation!r}") from None
        perturbation = Perturbation.uniform(nq, a, b)
    return perturbation.initial_state(gait)

