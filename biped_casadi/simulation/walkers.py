"""Batched closed-loop walking of the time-varying controller on its hybrid zero dynamics.

Why it is exact.  The correction v_c (eq. 17-18) makes y_c(0) = dy_c(0) = 0 at the start
of every step, from any starting state (y_i, dy_i are the output errors there).  With
the feedback-linearising law (12)-(13) the output then stays y_c = 0, so from every step
start the full-order closed loop IS its hybrid zero dynamics (eq. 19 with v^d + v_c):
the state of a scenario is (q_u, dq_u) and tau, q_a follows from the outputs (eq. 10),
the torques from eq. (12), the ground reaction from Newton's law for the centre of mass.
The output gains (Kp, Kd, eps) do not enter: the walker is the closed loop of every
gain, and agrees with the full-order :class:`~biped_casadi.simulation.full_order.Simulator` to its
integration accuracy (``tests/test_walker.py`` measures it).

Why it is fast.  One compiled step serves every design and every perturbation: the
output matrix M1 and the rejoin time t_c of v_c are runtime inputs, like the step's
(y_i, dy_i).  The reference q^d(tau) is the same for every scenario at the same tau, so
it is tabulated once per chunk of the step and shared by the whole batch.  A chunk of
T/8 is one ``mapaccum`` of RK4 nodes mapped over the active scenarios; the impact is
located inside its RK4 interval by a batched, safeguarded Newton iteration on the
length of the last step, as in the full-order simulator.

Validity.  Every node and every impact is checked with :mod:`biped_casadi.simulation.validity`
(the same conditions as the full-order simulator, torque limit included); a scenario
stops at its first invalid state.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass

import casadi as ca
import numpy as np

from ..control.reference import require_same_robot
from ..control.virtual_constraints import constraint_surface
from .full_order import SimulationOptions
from ..caching import cached
from ..numerics import jit_options, rk4_step
from ..control.output_law import (SECTION, actuated_torque, check_M1,
                                     coordinates_from_outputs, correction,
                                     decoupling_denominator, outputs, unactuated_acceleration)
from ..results import Result, internal
from .validity import first_violation, impact_violation, node_violations


__all__ = ["ZeroDynamicsWalker", "VirtualConstraintWalker", "WalkBatch",
           "zero_dynamics_walker", "virtual_constraint_walker"]

# rows of the node diagnostics after the nu torques
_ROWS = ("Fx", "Fz", "xsw", "zsw", "dzsw", "hip", "torso", "den")


@dataclass
class WalkBatch(Result):
    """The runs of a batch of scenarios (row i = scenario i).

    ``status`` is always 'complete' (``success``).  The per-scenario arrays are left out
    of ``to_dict()``.  The per-step arrays are NaN after a failure; the per-run
    quantities are taken over each run up to its end.

    Parameters
    ----------
    status : str
        'complete'.
    message : str
        How many runs were valid.
    steps : int
        Steps (impacts) each run was to walk.
    scenario_steps : int
        The steps taken, summed over the scenarios.
    run_status : numpy.ndarray
        (n,) 'ok' when every step was valid, else the status of the first invalid state
        (as :data:`biped_casadi.simulation.full_order.STATUSES`).
    fail_step : numpy.ndarray
        (n,) the index of the step where the run failed (``steps`` when ok).
    qu_error : numpy.ndarray
        (n, steps) q_u - q_u^d(T) just before each impact, rad.
    dqu_error : numpy.ndarray
        (n, steps) dq_u - dq_u^d(T) just before each impact, rad/s.
    duration : numpy.ndarray
        (n, steps) the duration of each step (tau at its impact), s.
    peak_torque : numpy.ndarray
        (n,) the largest ``|u_i|``, N m.
    min_normal_force : numpy.ndarray
        (n,) the smallest normal ground reaction of the stance foot, N.
    max_friction_ratio : numpy.ndarray
        (n,) the largest ratio of tangential to normal ground reaction.
    max_impulse_ratio : numpy.ndarray
        (n,) the largest ratio of tangential to normal impact impulse.
    """

    status: str
    message: str
    steps: int
    scenario_steps: int
    run_status: np.ndarray = internal()
    fail_step: np.ndarray = internal()
    qu_error: np.ndarray = internal()
    dqu_error: np.ndarray = internal()
    duration: np.ndarray = internal()
    peak_torque: np.ndarray = internal()
    min_normal_force: np.ndarray = internal()
    max_friction_ratio: np.ndarray = internal()
    max_impulse_ratio: np.ndarray = internal()

    SUCCESS = ("complete",)

    @property
    def ok(self) -> np.ndarray:
        """True where every step of the run was valid."""
        return self.run_status == "ok"

    @property
    def final_error(self) -> np.ndarray:
        """``max(|q_u err|, |dq_u err|)`` at the last step; inf where the run failed."""
        e = np.maximum(np.abs(self.qu_error[:, -1]), np.abs(self.dqu_error[:, -1]))
        return np.where(self.ok & np.isfinite(e), e, np.inf)

    def steps_to_converge(self, tol: float = 1e-3) -> np.ndarray:
        """The step of each run from which its error stays below ``tol`` to the end.

        The error of a step is ``max(|q_u err|, |dq_u err|)`` just before its impact.

        Parameters
        ----------
        tol : float
            Convergence threshold on the error (rad and rad/s).

        Returns
        -------
        numpy.ndarray
            (n,) 1-based step from which the error stays below ``tol`` to the end of
            the run; NaN where the run failed or never got there.
        """
        e = np.maximum(np.abs(self.qu_error), np.abs(self.dqu_error))
        below = e < tol
        out = np.full(len(e), np.nan)
        for i in np.flatnonzero(self.ok):
            k = below.shape[1]
            while k > 0 and below[i, k - 1]:
                k -= 1
            if k < below.shape[1]:
                out[i] = k + 1
        return out


class ZeroDynamicsWalker:
    """The hybrid zero dynamics of the time-varying controller as a batched simulator.

    Parameters
    ----------
    model : BipedModel
        The robot.
    gait : Reference
        The reference step, made for ``model``.
    options : SimulationOptions, optional
        Validity thresholds (mu, torque limit, ...) and ``horizon``, as the full-order
        simulator's; ``rk4_steps`` and ``jit`` below replace its integration settings.
    rk4_steps : int
        RK4 steps per reference step duration T (a multiple of 8).
    jit : bool
        Compile the step to C (needs a C compiler; a few seconds once, then faster).
    """

    def __init__(self, model, gait, options: SimulationOptions | None = None,
                 rk4_steps: int = 400, jit: bool = False):
        require_same_robot(model, gait)
        if isinstance(rk4_steps, bool) or not isinstance(rk4_steps, int) or rk4_steps < 8 \
                or rk4_steps % 8:
            raise ValueError(f"rk4_steps must be a positive multiple of 8, got {rk4_steps!r}")
        self.options = options if options is not None else SimulationOptions()
        self.model, self.gait = model, gait
        self.nq, self.nu = model.nq, model.nu
        self.T = gait.T
        self.rk4_steps, self.jit = rk4_steps, jit
        self.threads = max(1, min(os.cpu_count() or 1, 8))
        self.h = self.T / rk4_steps
        self.K = rk4_steps // 8
        o = self.options
        self.torque_limit = float(o.torque_limit if o.torque_limit is not None
                                  else model.params.torque_limit)
        self.min_hip_height = o.fall_height(model)
        self.horizon = min(o.horizon, (gait.t_max - self.h) / self.T)
        self.n_chunks = int(math.ceil(self.horizon * 8))
        self.ref_T = gait.state_at(self.T)
        t = np.linspace(0, self.T, 1001)
        D = np.array(model.D.map(t.size)(gait.q(t))).reshape(self.nq, self.nq, -1, order="F")
        self._D11, self._D12 = D[0, 0], D[0, 1:]
        self._table()
        self._build()

    @property
    def cache_key(self):
        """What the walker depends on: the gait's key, the options, rk4_steps and jit."""
        return (self.gait.cache_key, self.options, self.rk4_steps, self.jit)

    # ---------------------------------------------------------------- build
    def _table(self):
        """The reference (q^d, dq^d, ddq^d) at the three RK4 stage times of every node,
        one (9 nq x K) block per chunk of T/8."""
        nq = self.nq
        j = np.arange(self.n_chunks * self.K)
        tt = np.minimum(np.stack([j * self.h, (j + 0.5) * self.h, (j + 1) * self.h]),
                        self.gait.t_max)
        qd, dqd, ddqd = self.gait.evaluate(tt.ravel())
        R = np.vstack([qd, dqd, ddqd]).reshape(3 * nq, 3, -1).transpose(1, 0, 2)
        R = R.reshape(9 * nq, -1)                            # (stage 0; 1/2; 1) x nodes
        self._rtab = [R[:, c * self.K:(c + 1) * self.K] for c in range(self.n_chunks)]

    def _zero_dynamics(self, x, tau, R, P):
        """Configuration, rates, accelerations and the pieces of eq. (12) on the zero
        dynamics at one stage: x = (q_u, dq_u), R = (q^d, dq^d, ddq^d) at tau,
        P = (M1, t_c, y_i, dy_i)."""
        m, nq, nu = self.model, self.nq, self.nu
        M1, tc, yi, dyi = P[:nu], P[nu], P[nu + 1:2 * nu + 1], P[2 * nu + 1:]
        qd, dqd, ddqd = R[:nq], R[nq:2 * nq], R[2 * nq:]
        vc, dvc, ddvc = correction(tau, yi, dyi, tc)
        q = coordinates_from_outputs(M1, x[0], outputs(M1, qd) + vc)         # eq. (10)
        dq = coordinates_from_outputs(M1, x[1], outputs(M1, dqd) + dvc)
        ddv = outputs(M1, ddqd) + ddvc
        D, H = m.D(q), m.H(q, dq)
        ddqu = unactuated_acceleration(D, H, M1, ddv)                          # eq. (19)
        return q, dq, ddv, D, H, ddqu, M1

    def _diagnostics(self, x, tau, R, P):
        m = self.model
        q, dq, ddv, D, H, ddqu, M1 = self._zero_dynamics(x, tau, R, P)
        ddq = coordinates_from_outputs(M1, ddqu, ddv)
        u = actuated_torque(D, H, M1, ddqu, ddv)                               # eq. (12)
        Fx, Fz = m.ground_reaction_acc(q, dq, ddq)
        xs, zs = m.swing_foot(q)
        _, dzs = m.swing_foot_velocity(q, dq)
        den = decoupling_denominator(D[0, 0], D[0, 1:], M1)                    # eq. (24)
        return ca.vertcat(u, Fx, Fz, xs, zs, dzs, m.points(q)[1, m.hip_index], m.torso_angle(q),
                          den)

    def _build(self):
        m, nq, nu = self.model, self.nq, self.nu
        npar = 3 * nu + 1
        x, tau, h = ca.SX.sym("x", 2), ca.SX.sym("tau"), ca.SX.sym("h")
        P = ca.SX.sym("P", npar)
        R3 = ca.SX.sym("R3", 9 * nq)
        stage = {0.0: R3[:3 * nq], 0.5: R3[3 * nq:6 * nq], 1.0: R3[6 * nq:]}

        def rhs(xv, c):
            ddqu = self._zero_dynamics(xv, tau + c * h, stage[c], P)[5]
            return ca.vertcat(xv[1], ddqu)

        xn = rk4_step(rhs, x, h)
        jit = jit_options("-O2") if self.jit else {}
        node = ca.Function("zd_node", [x, tau, h, R3, P],
                           [ca.cse(xn), tau + h, ca.cse(self._diagnostics(xn, tau + h, stage[1.0], P))],
                           ["x", "tau", "h", "R3", "P"], ["x_next", "tau_next", "diag"], jit)
        acc = node.mapaccum("zd_chunk", self.K, [0, 1], [0, 1])
        xc, tc0 = ca.MX.sym("x", 2), ca.MX.sym("tau")
        Pc, Rt = ca.MX.sym("P", npar), ca.MX.sym("R", 9 * nq, self.K)
        X, TAU, DG = acc(xc, tc0, self.h, Rt, Pc)
        self.chunk = ca.Function("zd_chunk_fn", [xc, tc0, Pc, Rt], [X, TAU, DG])
        # diagnostics at a state with the reference taken from the gait (step start,
        # impact): R given explicitly
        R1 = ca.SX.sym("R", 3 * nq)
        self.diag = ca.Function("zd_diag", [x, tau, R1, P],
                                [ca.cse(self._diagnostics(x, tau, R1, P))], jit)
        # the last RK4 step, of length eta: the reference state r (n_state numbers,
        # e.g. (q_u^d, dq_u^d) of a gait) is integrated alongside from the node, so that
        # Newton's iteration on eta needs one call per iterate
        ref = self.gait.symbolic()
        nr = self.gait.n_state
        xr = ca.SX.sym("xr", 2 + nr)
        eta = ca.SX.sym("eta")

        def rhs_eta(zv, c):
            qd_, dqd_, ddqd_, dr_ = ref(tau + c * eta, zv[2:])
            R = ca.vertcat(qd_, dqd_, ddqd_)
            return ca.vertcat(zv[1], self._zero_dynamics(zv[:2], tau + c * eta, R, P)[5], dr_)

        ze = rk4_step(rhs_eta, xr, eta)
        qd_e, dqd_e, ddqd_e, _ = ref(tau + eta, ze[2:])
        q_e = self._zero_dynamics(ze[:2], tau + eta, ca.vertcat(qd_e, dqd_e, ddqd_e), P)[0]
        z_e = m.swing_foot(q_e)[1]
        self.event = ca.Function("zd_event", [xr, tau, eta, P],
                                 [z_e, ca.jacobian(z_e, eta), ze[:2]])
        # impact (eq. 2-3) and the next step's constants (eq. 17)
        q, dq, *_ = self._zero_dynamics(x, tau, R1, P)
        q_p, dq_p, F, _, v_old = m.impact_full(q, dq)
        M1 = P[:nu]
        q0, dq0, _ = self.gait.evaluate(0.0)
        y_n = outputs(M1, q_p) - outputs(M1, ca.DM(q0))
        dy_n = outputs(M1, dq_p) - outputs(M1, ca.DM(dq0))
        self.impact = ca.Function("zd_impact", [x, tau, R1, P],
                                  [ca.vertcat(q_p[0], dq_p[0]), y_n, dy_n, F, v_old[1]])
        qs, dqs, M1s = ca.SX.sym("q", nq), ca.SX.sym("dq", nq), ca.SX.sym("M1", nu)
        self.start_outputs = ca.Function(
            "zd_start", [qs, dqs, M1s],
            [outputs(M1s, qs) - outputs(M1s, ca.DM(q0)), outputs(M1s, dqs) - outputs(M1s, ca.DM(dq0))])

    @cached(maxsize=64)
    def _mapped(self, name: str, n: int) -> ca.Function:
        """``name`` mapped over n scenarios, on the machine's cores when n is large."""
        f = getattr(self, name)
        return f.map(n, "thread", self.threads) if n >= 4 * self.threads and self.threads > 1 \
            else f.map(n)

    def _reference(self, tau):
        """(q^d, dq^d, ddq^d) stacked, (3 nq, n) for the taus."""
        qd, dqd, ddqd = self.gait.evaluate(np.minimum(np.atleast_1d(tau), self.gait.t_max))
        return np.vstack([qd, dqd, ddqd])

    # ----------------------------------------------------------- scenarios
    def scenarios(self, q0, dq0, M1s, rejoin):
        """Initial (q_u, dq_u) and step constants P of scenarios from full start states.

        The arrays broadcast along the n scenarios.

        Parameters
        ----------
        q0, dq0 : array_like
            (n, nq) start configurations (rad) and velocities (rad/s) at tau = 0.
        M1s : array_like
            (n, nu) output matrices, one per scenario (or one, broadcast).
        rejoin : float or array_like
            (n,) rejoin times of v_c, fraction of T.

        Returns
        -------
        x0 : numpy.ndarray
            (n, 2) initial (q_u, dq_u), rad and rad/s.
        P : numpy.ndarray
            (n, 3 nu + 1) step constants (M1, t_c, y_i, dy_i): the design, the rejoin
            time in s and the output errors at the start of the step.
        """
        q0, dq0, M1s = (np.atleast_2d(np.asarray(a, float)) for a in (q0, dq0, M1s))
        n = max(len(q0), len(dq0), len(M1s), np.size(rejoin))
        q0, dq0, M1s = (np.broadcast_to(a, (n, a.shape[1])) for a in (q0, dq0, M1s))
        for i in range(min(n, len(M1s))):
            check_M1(M1s[i], self.nu)
        tc = np.broadcast_to(np.asarray(rejoin, float), (n,)) * self.T
        y, dy = (np.array(v) for v in self._mapped("start_outputs", n)(q0.T, dq0.T, M1s.T))
        P = np.vstack([M1s.T, tc[None, :], y, dy]).T
        return np.c_[q0[:, 0], dq0[:, 0]], P

    def den_scale(self, M1s) -> np.ndarray:
        """Per design, the largest ``|D11 - D12 M1|`` along the reference.

        It is the scale of the threshold below which the controller counts as singular.

        Parameters
        ----------
        M1s : array_like
            (n, nu) output matrices (or one (nu,)).

        Returns
        -------
        numpy.ndarray
            (n,) the maximum over the reference of ``|D11 - D12 M1|``.
        """
        d = decoupling_denominator(self._D11, self._D12, np.atleast_2d(M1s).T)
        return np.max(np.abs(d), axis=1)

    # ------------------------------------------------------------------ walk
    def walk(self, q0, dq0, M1s, rejoin=0.5, steps: int = 10) -> WalkBatch:
        """Walk every scenario from its full start state at tau = 0.

        Parameters
        ----------
        q0, dq0 : array_like
            (n, nq) start states (the start of a step).
        M1s : array_like
            (n, nu) output matrices (or one, broadcast).
        rejoin : float or array_like
            Rejoin time of v_c as a fraction of T, per scenario.
        steps : int
            Steps (impacts) to walk.

        Returns
        -------
        WalkBatch
        """
        x0, P = self.scenarios(q0, dq0, M1s, rejoin)
        return self._walk(x0, P, steps, tau0=0.0)

    def walk_from_section(self, x, M1s, rejoin=0.5, steps: int = 10) -> WalkBatch:
        """Walk from zero-dynamics states at the Poincaré section tau = 0.75 T.

        The states lie on the zero-dynamics manifold at the section (v_c = 0 there); a
        walk is ``steps`` applications of the restricted Poincaré map, with every state
        checked on the way.

        Parameters
        ----------
        x : array_like
            (n, 2) states (q_u, dq_u) at the section, rad and rad/s.
        M1s : array_like
            (n, nu) output matrices (or one, broadcast).
        rejoin : float or array_like
            Rejoin time of v_c as a fraction of T, per scenario.
        steps : int
            Steps (impacts) to walk.

        Returns
        -------
        WalkBatch
        """
        x = np.atleast_2d(np.asarray(x, float))
        n = len(x)
        M1s = np.broadcast_to(np.atleast_2d(np.asarray(M1s, float)), (n, self.nu))
        tc = np.broadcast_to(np.asarray(rejoin, float), (n,)) * self.T
        P = np.c_[M1s, tc, np.zeros((n, 2 * self.nu))]
        return self._walk(x.copy(), P, steps, tau0=SECTION * self.T)

    def _walk(self, x, P, steps, tau0):
        if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
            raise ValueError(f"steps must be a positive integer, got {steps!r}")
        n, nu = len(x), self.nu
        P = np.array(P, float)
        run = _Runs(n, steps)
        scale = self.den_scale(P[:, :nu])
        alive = np.ones(n, bool)
        for k in range(steps):
            idx = np.flatnonzero(alive)
            if idx.size == 0:
                break
            run.scenario_steps += idx.size
            start = tau0 if k == 0 else 0.0
            struck = self._single_support(k, idx, x, P, scale, run, alive, start)
            if struck is not None:
                self._impact(k, struck, x, P, scale, run, alive)
        return run.batch(steps)

    def _check(self, Dg, sign, scale, zprev=None):
        """First failing node (index along the last axis, status) of diagnostics
        (rows, m, K) of m scenarios."""
        nu = self.nu
        rows = {name: Dg[nu + i] for i, name in enumerate(_ROWS)}
        rows["u"] = Dg[:nu]
        rows["finite"] = np.all(np.isfinite(Dg), axis=0)
        masks = node_violations(rows, self.options, self.torque_limit, scale[:, None],
                                sign[:, None], zprev, min_hip_height=self.min_hip_height,
                                scuffing_ignored=self.model.scuffing_ignored)
        return first_violation(masks)

    def _single_support(self, k, idx, x, P, scale, run, alive, tau0):
        """Integrate step k of the scenarios ``idx`` from ``tau0`` to the strike; records
        failures; returns the struck scenarios' (local index, state and tau of the node
        before the strike, z_sw there and after) or None."""
        nu, m = self.nu, idx.size
        Pk = P[idx]
        R0 = np.repeat(self._reference(tau0), m, axis=1)
        D0 = np.array(self._mapped("diag", m)(x[idx].T, np.full((1, m), tau0), R0, Pk.T))
        sign = np.where(D0[nu + _ROWS.index("den")] >= 0, 1.0, -1.0)
        zsw0 = D0[nu + _ROWS.index("zsw")]
        first, which = self._check(D0[:, :, None], sign, scale[idx])
        which = np.where((which == "") & (zsw0 < -self.options.ground_tolerance) & (tau0 == 0),
                         "scuffed", which)
        run.track(idx, D0[:, :, None], nu)
        bad = which != ""
        run.fail(idx[bad], which[bad], k, alive)
        live = ~bad
        xcur, taucur, zprev = x[idx].copy(), np.full(m, tau0), zsw0.copy()
        before = np.full((m, 2), np.nan)
        t_before, z_a, z_b = np.zeros(m), np.zeros(m), np.zeros(m)
        struck = np.zeros(m, bool)
        c0 = int(round(tau0 / (self.T / 8)))
        for ci in range(c0, self.n_chunks):
            li = np.flatnonzero(live)
            if li.size == 0:
                break
            Xs, Ts, Dg = (np.array(v) for v in self._mapped("chunk", li.size)(
                xcur[li].T, taucur[li][None, :], Pk[li].T, self._rtab[ci]))
            Xs = Xs.reshape(2, li.size, self.K)
            Ts = Ts.reshape(li.size, self.K)
            Dg = Dg.reshape(-1, li.size, self.K)
            if (ci + 1) / 8 > self.horizon + 1e-12:                 # last partial chunk
                keep = Ts[0] <= self.horizon * self.T + 1e-12
                Xs, Ts, Dg = Xs[:, :, keep], Ts[:, keep], Dg[:, :, keep]
            zs, xsw = Dg[nu + _ROWS.index("zsw")], Dg[nu + _ROWS.index("xsw")]
            zp = np.concatenate([zprev[li][:, None], zs[:, :-1]], axis=1)
            with np.errstate(invalid="ignore"):
                strike = (zs < 0) & (xsw > self.model.scuff_zone) & (zp >= 0)
            i_strike = np.where(strike.any(axis=1), np.argmax(strike, axis=1), Ts.shape[1])
            masks_first, which = self._check(Dg, sign[li], scale[idx[li]], zp)
            failed = (which != "") & (masks_first < i_strike)
            upto = np.where(failed, masks_first + 1, i_strike)
            run.track(idx[li], Dg, nu, mask=np.arange(Ts.shape[1])[None, :] < upto[:, None])
            run.fail(idx[li[failed]], which[failed], k, alive)
            hit = ~failed & (i_strike < Ts.shape[1])
            for j in np.flatnonzero(hit):
                s_, g_ = i_strike[j], li[j]
                before[g_] = xcur[g_] if s_ == 0 else Xs[:, j, s_ - 1]
                t_before[g_] = taucur[g_] if s_ == 0 else Ts[j, s_ - 1]
                z_a[g_] = zprev[g_] if s_ == 0 else zs[j, s_ - 1]
                z_b[g_] = zs[j, s_]
                struck[g_] = True
            cont = ~failed & ~hit
            live[li[~cont]] = False
            xcur[li[cont]] = Xs[:, cont, -1].T
            taucur[li[cont]] = Ts[cont, -1]
            zprev[li[cont]] = zs[cont, -1]
        missing = alive[idx] & ~struck
        run.fail(idx[missing], np.full(missing.sum(), "no_impact", dtype=object), k, alive)
        si = np.flatnonzero(struck & alive[idx])
        if si.size == 0:
            return None
        return idx[si], before[si], t_before[si], z_a[si], z_b[si], sign[si]

    def _impact(self, k, struck, x, P, scale, run, alive):
        """Locate the impact of the struck scenarios (Newton on the last RK4 step), check
        the pre-impact state and the impulse, apply the impact map and the next step's
        constants."""
        gi, xa, ta, za, zb, sign = struck
        nu, m = self.nu, gi.size
        Ps = P[gi]
        lo, hi = np.zeros(m), np.full(m, self.h)
        with np.errstate(invalid="ignore", divide="ignore"):
            eta = np.where(za > zb, self.h * za / (za - zb), self.h)
        ev = self._mapped("event", m)
        xr = np.vstack([xa.T, self.gait.states(ta)])

        def event(eta):
            return ev(xr, ta[None, :], eta[None, :], Ps.T)

        for _ in range(40):
            zz, dz, _ = event(eta)
            zz, dz = np.array(zz).ravel(), np.array(dz).ravel()
            lo = np.where(zz > 0, eta, lo)
            hi = np.where(zz > 0, hi, eta)
            with np.errstate(invalid="ignore", divide="ignore"):
                new = np.where(dz != 0, eta - zz / dz, 0.5 * (lo + hi))
            new = np.where((lo < new) & (new < hi), new, 0.5 * (lo + hi))
            done = (np.abs(zz) < 1e-15) | (np.abs(new - eta) < 1e-17)
            eta = np.where(np.abs(zz) < 1e-15, eta, new)
            if done.all():
                break
        xe = np.array(event(eta)[2]).T
        tm = ta + eta
        Rm = self._reference(tm)
        Dm = np.array(self._mapped("diag", m)(xe.T, tm[None, :], Rm, Ps.T))
        first, which = self._check(Dm[:, :, None], sign, scale[gi])
        which = np.where((which == "") & ~(Dm[nu + _ROWS.index("dzsw")] < 0), "scuffed", which)
        run.track(gi, Dm[:, :, None], nu)
        xn, yn, dyn, F, vl = (np.array(v) for v in self._mapped("impact", m)(
            xe.T, tm[None, :], Rm, Ps.T))
        F, vl = F.T, vl.ravel()
        run.record_impact(gi, k, xe - self.ref_T[None, :], tm, F)
        finite = np.all(np.isfinite(np.c_[xn.T, yn.T, dyn.T, F]), axis=1)
        imp = impact_violation(F, vl, finite, self.options)
        which = np.where(which == "", imp, which)
        bad = which != ""
        run.fail(gi[bad], which[bad], k, alive)
        go = ~bad
        x[gi[go]] = xn.T[go]
        P[gi[go], nu + 1:2 * nu + 1] = yn.T[go]
        P[gi[go], 2 * nu + 1:] = dyn.T[go]


class _Runs:
    """Accumulates the per-scenario results of a walk."""

    def __init__(self, n, steps):
        self.status = np.full(n, "ok", dtype=object)
        self.fail_step = np.full(n, steps)
        self.qu = np.full((n, steps), np.nan)
        self.dqu = np.full((n, steps), np.nan)
        self.dur = np.full((n, steps), np.nan)
        self.peak_u = np.zeros(n)
        self.min_fz = np.full(n, np.inf)
        self.max_fr = np.zeros(n)
        self.max_ir = np.zeros(n)
        self.scenario_steps = 0

    def fail(self, gi, which, k, alive):
        first = self.status[gi] == "ok"
        self.status[gi[first]] = np.asarray(which)[first]
        self.fail_step[gi[first]] = k
        alive[gi] = False

    def track(self, gi, Dg, nu, mask=None):
        if mask is None:
            mask = np.ones(Dg.shape[1:], bool)
        fx, fz = Dg[nu + _ROWS.index("Fx")], Dg[nu + _ROWS.index("Fz")]
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            pu = np.where(mask, np.max(np.abs(Dg[:nu]), axis=0), 0)
            ratio = np.where(mask, np.abs(fx) / np.maximum(fz, 1e-300), 0)
        self.peak_u[gi] = np.maximum(self.peak_u[gi], np.nanmax(pu, axis=1))
        self.min_fz[gi] = np.minimum(self.min_fz[gi], np.nanmin(np.where(mask, fz, np.inf), axis=1))
        self.max_fr[gi] = np.maximum(self.max_fr[gi], np.nanmax(ratio, axis=1))

    def record_impact(self, gi, k, err, tm, F):
        self.qu[gi, k], self.dqu[gi, k] = err[:, 0], err[:, 1]
        self.dur[gi, k] = tm
        with np.errstate(invalid="ignore", divide="ignore"):
            ir = np.where(F[:, 1] > 0, np.abs(F[:, 0]) / F[:, 1], np.inf)
        self.max_ir[gi] = np.maximum(self.max_ir[gi], ir)

    def batch(self, steps) -> WalkBatch:
        st = self.status.astype(str)
        n_ok = int(np.sum(st == "ok"))
        return WalkBatch(status="complete", message=f"{n_ok} of {len(st)} runs valid",
                         steps=steps, scenario_steps=self.scenario_steps, run_status=st,
                         fail_step=self.fail_step, qu_error=self.qu, dqu_error=self.dqu,
                         duration=self.dur, peak_torque=self.peak_u,
                         min_normal_force=self.min_fz, max_friction_ratio=self.max_fr,
                         max_impulse_ratio=self.max_ir)


@cached(maxsize=4)
def zero_dynamics_walker(model, gait, options: SimulationOptions | None = None,
                         rk4_steps: int = 400, jit: bool = False) -> ZeroDynamicsWalker:
    """The :class:`ZeroDynamicsWalker` of a gait and options, built once (memoised).

    Parameters
    ----------
    model : BipedModel
        The robot.
    gait : Reference
        The reference step, made for ``model``.
    options : SimulationOptions, optional
        Validity thresholds and horizon.
    rk4_steps : int
        RK4 steps per reference step duration T (a multiple of 8).
    jit : bool
        Compile the step to C.

    Returns
    -------
    ZeroDynamicsWalker
        The same object for the same arguments.
    """
    return ZeroDynamicsWalker(model, gait, options, rk4_steps, jit)


class VirtualConstraintWalker:
    """Virtual constraints on their hybrid zero dynamics, batched, integrated in the phase.

    On the constraint surface the configuration is a function of the phase theta alone,
    q = Q(theta), and the state is (theta, w = dtheta/dt); the swing foot strikes at the
    fixed phase theta^- (where z_sw(Q(theta)) = 0), so a step is an integration in theta
    from the start phase to theta^- (RK4 on w and on the time, dt/dtheta = 1/w), with the
    ground reaction and the torques of the exact zero dynamics checked at every node
    (:mod:`biped_casadi.simulation.validity`), then the impact map.  Virtual constraints are impact
    invariant: the state lands on the surface again, at theta^+ = c q^+.

    Parameters
    ----------
    model : BipedModel
        The robot.
    gait : Reference
        The reference step the virtual constraints are fitted to.
    options : SimulationOptions, optional
        Validity thresholds.
    nodes : int
        RK4 nodes from the start phase of a step to its impact.
    jit : bool
        Compile the step to C.
    """

    def __init__(self, model, gait, options: SimulationOptions | None = None, nodes: int = 200,
                 jit: bool = False):
        require_same_robot(model, gait)
        self._jit = jit_options("-O2") if jit else {}
        self.threads = max(1, min(os.cpu_count() or 1, 8))
        self.options = options if options is not None else SimulationOptions()
        self.model, self.gait = model, gait
        self.nu = model.nu
        self.vmap = constraint_surface(model, gait)
        self.theta_s = self.vmap.phase(gait.q(SECTION * gait.T))
        self.nodes = nodes
        o = self.options
        self.torque_limit = float(o.torque_limit if o.torque_limit is not None
                                  else model.params.torque_limit)
        self.min_hip_height = o.fall_height(model)
        self.ref_T = gait.state_at(gait.T)
        self._build()
        ths = np.linspace(self.vmap.theta_plus, self.vmap.theta_minus, 801)
        self.den_scale = float(np.max(np.abs(np.array(self.vmap.curve.map(ths.size)(
            ths[None, :])[2]))))

    def _build(self):
        m, vm = self.model, self.vmap
        th, w, t, hs = ca.SX.sym("theta"), ca.SX.sym("w"), ca.SX.sym("t"), ca.SX.sym("h")
        z = ca.vertcat(w, t)

        def rhs(zv, c):
            return ca.vertcat(vm.zero_dynamics(th + c * hs, zv[0]), 1 / zv[0])

        zn = rk4_step(rhs, z, hs)
        thn = th + hs
        q, Q1, den = vm.curve(thn)
        Q2 = vm.curve_second(thn)
        wn = zn[0]
        ddth = wn * vm.zero_dynamics(thn, wn)
        dq = Q1 * wn
        ddq = Q1 * ddth + Q2 * wn**2
        D, H = m.D(q), m.H(q, dq)
        u = (ca.mtimes(D, ddq) + H)[1:]
        Fx, Fz = m.ground_reaction_acc(q, dq, ddq)
        xs, zs = m.swing_foot(q)
        _, dzs = m.swing_foot_velocity(q, dq)
        diag = ca.vertcat(u, Fx, Fz, xs, zs, dzs, m.points(q)[1, m.hip_index],
                          m.torso_angle(q), den)
        node = ca.Function("vc_node", [z, th, hs], [ca.cse(zn), thn, ca.cse(diag)], self._jit)
        self.start_node = node                   # with h = 0: the diagnostics of a state
        acc = node.mapaccum("vc_nodes", self.nodes, [0, 1], [0, 1])
        zc, thc, hc = ca.MX.sym("z", 2), ca.MX.sym("theta"), ca.MX.sym("h")
        self.chunk = ca.Function("vc_step", [zc, thc, hc], list(acc(zc, thc, hc)))
        qm, Q1m, _ = vm.curve(vm.theta_minus)
        wm = ca.SX.sym("w_minus")
        q_p, dq_p, F, _, v_old = m.impact_full(qm, Q1m * wm)
        self.impact = ca.Function("vc_impact", [wm], [ca.mtimes(ca.DM(vm.vc.c).T, dq_p), F,
                                                     v_old[1], Q1m[0] * wm])

    @cached(maxsize=16)
    def _mapped(self, name: str, n: int) -> ca.Function:
        f = getattr(self, name)
        return f.map(n, "thread", self.threads) if n >= 4 * self.threads and self.threads > 1 \
            else f.map(n)

    def section_states(self, x):
        """The states (theta, w) on the constraint surface with given (q_u, dq_u).

        theta is the phase whose configuration has that q_u (Newton on the curve), and
        w = dq_u / (dq_u/dtheta).

        Parameters
        ----------
        x : array_like
            (n, 2) states (q_u, dq_u), rad and rad/s.

        Returns
        -------
        theta, w : numpy.ndarray
            (n,) phases (rad) and phase rates (rad/s).
        """
        x = np.atleast_2d(np.asarray(x, float))
        vm = self.vmap
        th = np.full(len(x), self.theta_s)
        curve = vm.curve.map(len(x))
        for _ in range(50):
            Q, Q1, _ = (np.array(v) for v in curve(th[None, :]))
            step = (Q[0] - x[:, 0]) / Q1[0]
            th = th - step
            if np.max(np.abs(step)) < 1e-14:
                break
        Q, Q1, _ = (np.array(v) for v in curve(th[None, :]))
        return th, x[:, 1] / Q1[0]

    def walk_from_section(self, x, steps: int = 10) -> WalkBatch:
        """Walk from zero-dynamics states with the given (q_u, dq_u) for ``steps`` impacts.

        See :meth:`ZeroDynamicsWalker.walk_from_section`.

        Parameters
        ----------
        x : array_like
            (n, 2) states (q_u, dq_u) on the constraint surface, rad and rad/s.
        steps : int
            Steps (impacts) to walk.

        Returns
        -------
        WalkBatch
        """
        th, w = self.section_states(x)
        return self.walk(th, w, steps)

    def walk(self, theta, w, steps: int = 10) -> WalkBatch:
        """Walk from phases ``theta`` with rates ``w`` for ``steps`` impacts.

        Parameters
        ----------
        theta : array_like
            (n,) start phases, rad.
        w : array_like
            (n,) start phase rates dtheta/dt, rad/s.
        steps : int
            Steps (impacts) to walk.

        Returns
        -------
        WalkBatch
        """
        vm, nu, o = self.vmap, self.nu, self.options
        theta, w = np.array(theta, float), np.array(w, float)
        n = theta.size
        run = _Runs(n, steps)
        alive = np.ones(n, bool)
        direction = np.sign(vm.theta_minus - vm.theta_plus)
        for k in range(steps):
            idx = np.flatnonzero(alive)
            if idx.size == 0:
                break
            run.scenario_steps += idx.size
            m_ = idx.size
            hs = (vm.theta_minus - theta[idx]) / self.nodes
            stalled = ~(w[idx] * direction > 0) | ~(hs * direction > 0)
            z0 = np.vstack([w[idx], np.zeros(m_)])
            _, _, D0 = (np.array(v) for v in self._mapped("start_node", m_)(
                z0, theta[idx][None, :], np.zeros((1, m_))))
            Z, TH, Dg = (np.array(v) for v in self._mapped("chunk", m_)(
                z0, theta[idx][None, :], hs[None, :]))
            Z = np.concatenate([z0[:, :, None], Z.reshape(2, m_, self.nodes)], axis=2)
            Dg = np.concatenate([D0[:, :, None], Dg.reshape(-1, m_, self.nodes)], axis=2)
            ws = Z[0]
            rows = {name: Dg[nu + i] for i, name in enumerate(_ROWS)}
            rows["u"] = Dg[:nu]
            rows["finite"] = np.all(np.isfinite(Dg), axis=0) & np.all(np.isfinite(Z), axis=0)
            masks = node_violations(rows, o, self.torque_limit, self.den_scale,
                                    np.sign(rows["den"][:, :1]),
                                    min_hip_height=self.min_hip_height,
                                    scuffing_ignored=self.model.scuffing_ignored)
            masks["no_impact"] = rows["finite"] & ~(ws * direction > 0)   # stalls, falls back
            first, which = first_violation(masks)
            run.track(idx, Dg, nu, mask=np.arange(self.nodes + 1)[None, :]
                      < np.minimum(first + 1, self.nodes + 1)[:, None])
            which = np.where(stalled & (which == ""), "no_impact", which)
            bad = which != ""
            run.fail(idx[bad], which[bad], k, alive)
            ok = np.flatnonzero(~bad)
            if ok.size == 0:
                continue
            gi = idx[ok]
            wm, tm = ws[ok, -1], Z[1, ok, -1]
            dz_dt = rows["dzsw"][ok, -1]
            wp, F, vl, dqu = (np.array(v) for v in self._mapped("impact", ok.size)(wm[None, :]))
            F, vl, wp = F.T, vl.ravel(), wp.ravel()
            err = np.c_[np.full(ok.size, float(np.array(vm.curve(vm.theta_minus)[0])[0, 0])),
                        dqu.ravel()] - self.ref_T[None, :]
            run.record_impact(gi, k, err, tm, F)
            imp = impact_violation(F, vl, np.isfinite(wp) & np.all(np.isfinite(F), axis=1), o)
            imp = np.where((imp == "") & ~(dz_dt < 0), "scuffed", imp)
            badi = imp != ""
            run.fail(gi[badi], imp[badi], k, alive)
            go = gi[~badi]
            theta[go] = vm.theta_plus
            w[go] = wp[~badi]
        return run.batch(steps)


@cached(maxsize=4)
def virtual_constraint_walker(model, gait, options: SimulationOptions | None = None,
                              nodes: int = 200, jit: bool = False) -> VirtualConstraintWalker:
    """The :class:`VirtualConstraintWalker` of a gait (memoised).

    Parameters
    ----------
    model : BipedModel
        The robot.
    gait : Reference
        The reference step the virtual constraints are fitted to.
    options : SimulationOptions, optional
        Validity thresholds.
    nodes : int
        RK4 nodes from the start phase of a step to its impact.
    jit : bool
        Compile the step to C.

    Returns
    -------
    VirtualConstraintWalker
        The same object for the same arguments.
    """
    return VirtualConstraintWalker(model, gait, options, nodes, jit)
