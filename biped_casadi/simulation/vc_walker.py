"""Batched walking of virtual constraints on their hybrid zero dynamics, in the phase.

On the constraint surface (:class:`~biped_casadi.control.ConstraintSurface`) the
configuration is a function of the phase alone and the state is (theta, w = dtheta/dt);
the swing foot strikes at the fixed phase theta^-, so a step is an integration in theta
from the start phase to theta^-, with every node checked
(:mod:`biped_casadi.simulation.validity`), then the impact map.  Its outcomes are those
of every simulator (:class:`~biped_casadi.simulation.outcome.WalkBatch`).
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from ..caching import cached
from ..control.output_law import SECTION
from ..control.reference import require_same_robot
from ..control.virtual_constraints import constraint_surface
from ..numerics import jit_options, rk4_step
from .kernel import Diagnostics, mapped
from .options import SimulationOptions
from .outcome import OutcomeRecorder, WalkBatch
from .validity import (Limits, first_violation, impact_violation, node_violations,
                       strike_violation)

__all__ = ["VirtualConstraintWalker", "virtual_constraint_walker"]


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
        self.options = options if options is not None else SimulationOptions()
        self.model, self.gait = model, gait
        self.nu = model.nu
        self.vmap = constraint_surface(model, gait)
        self.theta_s = self.vmap.phase(gait.q(SECTION * gait.T))
        self.nodes = nodes
        self.limits = Limits.of(self.options, model)
        self.schema = Diagnostics(self.nu, outputs=False)
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
        diag = self.schema.vector(m, q, dq, u, Fx, Fz, den)
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
        return mapped(getattr(self, name), n)

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
        vm, S = self.vmap, self.schema
        theta, w = np.array(theta, float), np.array(w, float)
        n = theta.size
        run = OutcomeRecorder(n, steps)
        alive = np.ones(n, bool)
        direction = np.sign(vm.theta_minus - vm.theta_plus)
        q_u_minus = float(np.array(vm.curve(vm.theta_minus)[0])[0, 0])
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
            rows = S.rows(Dg, np.all(np.isfinite(Z), axis=0))
            masks = node_violations(rows, self.limits, self.den_scale,
                                    np.sign(rows["den"][:, :1]))
            masks["no_impact"] = rows["finite"] & ~(ws * direction > 0)   # stalls, falls back
            first, which = first_violation(masks)
            run.track(idx, S.row(Dg, "u"), S.row(Dg, "Fx"), S.row(Dg, "Fz"),
                      np.arange(self.nodes + 1)[None, :]
                      < np.minimum(first + 1, self.nodes + 1)[:, None])
            which = np.where(stalled & (which == ""), "no_impact", which)
            which = np.where(which == "", strike_violation(rows["dzsw"][:, -1]), which)
            bad = which != ""
            run.fail(idx[bad], which[bad], k)
            alive[idx[bad]] = False
            ok = np.flatnonzero(~bad)
            if ok.size == 0:
                continue
            gi = idx[ok]
            wm, tm = ws[ok, -1], Z[1, ok, -1]
            wp, F, vl, dqu = (np.array(v) for v in self._mapped("impact", ok.size)(wm[None, :]))
            F, vl, wp = F.T, vl.ravel(), wp.ravel()
            err = np.c_[np.full(ok.size, q_u_minus), dqu.ravel()] - self.ref_T[None, :]
            run.impact(gi, k, err[:, 0], err[:, 1], tm, F)
            imp = impact_violation(F, vl, np.isfinite(wp) & np.all(np.isfinite(F), axis=1),
                                   self.limits)
            badi = imp != ""
            run.fail(gi[badi], imp[badi], k)
            alive[gi[badi]] = False
            go = gi[~badi]
            theta[go] = vm.theta_plus
            w[go] = wp[~badi]
        return run.batch()


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
