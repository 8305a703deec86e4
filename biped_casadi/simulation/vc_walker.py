"""Batched walking of virtual constraints on their hybrid zero dynamics, in the phase.

On the constraint surface (:class:`~biped_casadi.control.ConstraintSurface`) the
configuration is a function of the phase alone and the state is (theta, w = dtheta/dt);
the swing foot strikes at the phase theta^- where it reaches the ground, so a step is an
integration in theta from the start phase to theta^-, with every node checked
(:mod:`biped_casadi.simulation.validity`), then the impact map.  Its outcomes are those
of every simulator (:class:`~biped_casadi.simulation.outcome.WalkBatch`).

From any state at the start of a step the controller's phase-based correction h_c makes
the outputs and their rates zero (:func:`~biped_casadi.control.phase_correction`), so the
closed loop is exactly the motion on the step's corrected surface: the walker starts
from full states (:meth:`VirtualConstraintWalker.walk_from_states`), and on uneven ground
(``terrain``), where an impact at another height lands off the surface, the next step
starts from the post-impact state in the same way.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from ..caching import cached
from ..control.output_law import SECTION
from ..control.reference import require_reference, require_same_robot
from ..control.virtual_constraints import constraint_surface, rejoin_phase
from ..numerics import as_count, compiled, rk4_step
from ..simd import kernels
from .kernel import Diagnostics, call_batched, mapped, threads
from .options import SimulationOptions
from .outcome import OutcomeRecorder, WalkBatch
from .terrain import ground_levels, step_heights
from .validity import (Limits, first_violation, impact_violation, node_violations,
                       start_violation, strike_violation)

__all__ = ["VirtualConstraintWalker", "virtual_constraint_walker"]


class VirtualConstraintWalker:
    """Virtual constraints on their hybrid zero dynamics, batched, integrated in the phase.

    On the (corrected) constraint surface the configuration is a function of the phase
    theta alone, q = Q(theta; p), and the state is (theta, w = dtheta/dt); the swing foot
    strikes at the phase theta^- where z_sw(Q(theta^-)) is the ground height (near the
    reference's impact), so a step is an integration in theta from the start phase to
    theta^- (RK4 on w and on the time, dt/dtheta = 1/w), with the ground reaction and
    the torques of the exact zero dynamics checked at every node
    (:mod:`biped_casadi.simulation.validity`), then the impact map.  On flat ground
    virtual constraints are impact invariant (the state lands on the surface again, at
    theta^+ = c q^+); elsewhere the next step starts on its corrected surface.

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
        self._jit = jit
        self.options = options if options is not None else SimulationOptions()
        if not isinstance(self.options, SimulationOptions):
            raise ValueError(f"options must be a SimulationOptions, got "
                             f"{type(self.options).__name__}")
        if self.options.saturate:
            raise ValueError("options: saturate needs the full-order simulator (the walker is "
                             "the zero dynamics, exact only with the law's own torques)")
        self.model, self.gait = model, gait
        self.nu = model.nu
        self.n_par = 1 + 2 * self.nu
        self.vmap = constraint_surface(gait)
        self.theta_s = self.vmap.phase(gait.q(SECTION * gait.T))
        self.nodes = as_count(nodes, "nodes")
        self.limits = Limits.of(self.options, model, gait)
        self.schema = Diagnostics(self.nu, outputs=False)
        self.ref_T = gait.state_at(gait.T)
        self.direction = float(np.sign(self.vmap.theta_minus - self.vmap.theta_plus))
        self._build()
        ths = np.linspace(self.vmap.theta_plus, self.vmap.theta_minus, 801)
        self.den_scale = float(np.max(np.abs(np.array(self.vmap.curve.map(ths.size)(
            ths[None, :])[2]))))

    def _build(self):
        m, vm = self.model, self.vmap
        th, w, t, hs = ca.SX.sym("theta"), ca.SX.sym("w"), ca.SX.sym("t"), ca.SX.sym("h")
        p = ca.SX.sym("p", self.n_par)
        # the rejoin phase is an input: the compiled nodes hold no number of the gait
        # but its constraints' spline (CasADi's code, compiled apart), so the gaits of a
        # robot share their node's machine code (biped_casadi.simd)
        tc = ca.SX.sym("t_c")
        self.t_c = rejoin_phase(vm.vc)
        z = ca.vertcat(w, t)
        sgn = self.direction

        def corrected(thv, wv):
            return vm.corrected_expressions(thv, wv, p, tc)

        # RK4 on (xi, t) with xi = w^2: d xi/d theta = 2 d2theta/dt2 is regular where the
        # phase rate w stalls (dw/dtheta = d2theta/dt2 / w is not, and RK4 on w can step
        # over a turning point); a stage past the turn has xi < 0, so w and t are NaN.
        def rhs(zv, c):
            wv = sgn * ca.sqrt(zv[0])
            return ca.vertcat(2 * corrected(th + c * hs, wv)[5], 1 / wv)

        zx = rk4_step(rhs, ca.vertcat(w**2, t), hs)
        zn = ca.vertcat(sgn * ca.sqrt(zx[0]), zx[1])
        thn = th + hs
        wn = zn[0]
        q, Q1, Q2, dw, den, _ = corrected(thn, wn)
        ddth = wn * dw
        dq = Q1 * wn
        ddq = Q1 * ddth + Q2 * wn**2
        D, H = m.D(q), m.H(q, dq)
        u = (ca.mtimes(D, ddq) + H)[1:]
        Fx, Fz = m.ground_reaction_acc(q, dq, ddq)
        diag = self.schema.vector(m, q, dq, u, Fx, Fz, den)
        node_tc = ca.Function("vc_node", [z, th, hs, p, tc], [ca.cse(zn), thn, ca.cse(diag)])
        node = ca.Function("vc_node_gait", [z, th, hs, p], node_tc(z, th, hs, p, self.t_c))
        self.node = node
        self._build_steps(th, p)
        # four scenarios per SIMD vector where the machine allows (biped_casadi.simd):
        # the nodes (the step's ends run once per step, on CasADi's Functions)
        self._simd = kernels({"chunk": (node_tc, 2, ["sample", "sample", "const"])},
                             "vc_walker") if self._jit else None
        if self._jit and self._simd is None:   # compiled once per content, kept on disk
            node = compiled(node, "-O2")
        self.start_node = node                   # with h = 0: the diagnostics of a state
        acc = node.mapaccum("vc_nodes", self.nodes, [0, 1], [0, 1])
        zc, thc, hc = ca.MX.sym("z", 2), ca.MX.sym("theta"), ca.MX.sym("h")
        pc = ca.MX.sym("p", self.n_par)
        self.chunk = ca.Function("vc_step", [zc, thc, hc, pc], list(acc(zc, thc, hc, pc)))

    def _build_steps(self, th, p):
        """The Functions of a step's ends: the foot on the surface, the impact, the start."""
        m, vm = self.model, self.vmap
        self.foot = vm.corrected_foot
        wm = ca.SX.sym("w_minus")
        qm, Q1m, _, _, _, _ = vm.corrected(th, wm, p)
        q_p, dq_p, F, _, v_old = m.impact_full(qm, Q1m * wm)
        th_p, w_p, p_p = vm.step_start(q_p, dq_p)
        self.impact = ca.Function("vc_impact", [th, wm, p],
                                  [th_p, w_p, p_p, F, v_old[1], qm[0], Q1m[0] * wm])
        self.pre_impact = ca.Function("vc_pre_impact", [th, wm, p], [qm, Q1m * wm])
        self.start = vm.step_start

    @cached(maxsize=16)
    def _mapped(self, name: str, n: int) -> ca.Function:
        return mapped(getattr(self, name), n)

    def _batch(self, name: str, *args) -> list:
        """``name`` over the scenarios (:func:`~biped_casadi.simulation.kernel.call_batched`)."""
        return call_batched(self._simd, self._mapped, name, *args)

    def _nodes(self, z0, theta, hs, p, K):
        """K nodes from (w, t) = z0 at phases theta, steps hs: z (2, m, K), theta (m, K),
        diagnostics (rows, m, K) after each."""
        m_ = z0.shape[1]
        if self._simd is not None:
            Z, TH, Dg = self._simd["chunk"](z0, theta[None, :], hs[None, :], p.T, [self.t_c],
                                            K=K, threads=threads())
            return Z, TH[0], Dg
        f = self._mapped("chunk" if K == self.nodes else "start_node", m_)
        Z, TH, Dg = (np.array(v) for v in f(z0, theta[None, :], hs[None, :], p.T))
        return Z.reshape(2, m_, K), TH.reshape(m_, K), Dg.reshape(-1, m_, K)

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

    def walk_from_section(self, x, steps: int = 10, terrain=None) -> WalkBatch:
        """Walk from zero-dynamics states with the given (q_u, dq_u) for ``steps`` impacts.

        See :meth:`ZeroDynamicsWalker.walk_from_section`.

        Parameters
        ----------
        x : array_like
            (n, 2) states (q_u, dq_u) on the constraint surface, rad and rad/s.
        steps : int
            Steps (impacts) to walk.
        terrain : Terrain or array_like, optional
            Ground heights, one per step (:mod:`biped_casadi.simulation.terrain`).

        Returns
        -------
        WalkBatch
        """
        th, w = self.section_states(x)
        return self.walk(th, w, steps, terrain)

    def walk_from_states(self, q0, dq0, steps: int = 10, terrain=None) -> WalkBatch:
        """Walk from full states at the start of a step (the controller's step start).

        Exact for the virtual-constraint controller with its correction (the default):
        from the start of every step the closed loop moves on the step's corrected
        surface.

        Parameters
        ----------
        q0, dq0 : array_like
            (n, nq) start states, rad and rad/s.
        steps : int
            Steps (impacts) to walk.
        terrain : Terrain or array_like, optional
            Ground heights, one per step.

        Returns
        -------
        WalkBatch
        """
        q0, dq0 = (np.atleast_2d(np.asarray(a, float)) for a in (q0, dq0))
        th, w, p = self._batch("start", q0.T, dq0.T)
        return self.walk(th.ravel(), w.ravel(), steps, terrain, p=p.T, step_start=True)

    def _strike_phase(self, height, p):
        """Per scenario, the phase near theta^- where the swing foot is at ``height`` on
        the step's corrected surface (Newton), NaN where it does not converge."""
        n = len(height)
        th = np.full(n, self.vmap.theta_minus)
        for _ in range(40):
            _, z, dz = (v.ravel() for v in self._batch("foot", th[None, :], p.T))
            with np.errstate(invalid="ignore", divide="ignore"):
                step = (z - height) / dz
            th = th - step
            if not np.any(np.abs(step) > 1e-14):
                break
        with np.errstate(invalid="ignore"):
            bad = ~(np.abs(step) <= 1e-10)
        return np.where(bad, np.nan, th)

    def walk_step(self, q0, dq0):
        """One step from full start states, and the states just before its impact.

        For chaining walkers of different gaits (a speed profile,
        :func:`~biped_casadi.simulation.speed_profile.walk_profile`).

        Parameters
        ----------
        q0, dq0 : array_like
            (n, nq) start states, rad and rad/s.

        Returns
        -------
        batch : WalkBatch
            The step's outcome (one step).
        q_minus, dq_minus : numpy.ndarray
            (n, nq) the state before the impact of the scenarios that struck (NaN for
            the others; use those whose step was valid).
        """
        q0, dq0 = (np.atleast_2d(np.asarray(a, float)) for a in (q0, dq0))
        n = max(len(q0), len(dq0))
        q0, dq0 = (np.broadcast_to(a, (n, a.shape[1])) for a in (q0, dq0))
        th, w, p = self._batch("start", q0.T, dq0.T)
        nq = self.model.nq
        ends = np.full((n, 2 * nq), np.nan)
        batch = self.walk(th.ravel(), w.ravel(), 1, p=p.T, step_start=True, ends=ends)
        return batch, ends[:, :nq], ends[:, nq:]

    def _strike(self, thm, wm, p, rows, ends=None):
        """The impact map at the strike phases ``thm`` with rates ``wm`` of scenarios
        ``rows`` (step constants ``p``, (m, 1 + 2 nu)); their pre-impact states (q, dq)
        into ``ends[rows]`` when given."""
        if ends is not None:
            ends[rows] = np.vstack(self._batch("pre_impact", thm[None, :], wm[None, :], p.T)).T
        return self._batch("impact", thm[None, :], wm[None, :], p.T)

    def walk(self, theta, w, steps: int = 10, terrain=None, p=None,
             step_start: bool = False, ends=None) -> WalkBatch:
        """Walk from phases ``theta`` with rates ``w`` for ``steps`` impacts.

        Parameters
        ----------
        theta : array_like
            (n,) start phases, rad.
        w : array_like
            (n,) start phase rates dtheta/dt, rad/s.
        steps : int
            Steps (impacts) to walk.
        terrain : Terrain or array_like, optional
            Ground heights, one per step (default flat).
        p : array_like, optional
            (n, 1 + 2 nu) the first step's correction constants (default none: the
            states are on the constraint surface).
        step_start : bool
            Whether the first step starts at its beginning (the swing foot is checked
            to be above the ground there); else it starts inside the step.
        ends : numpy.ndarray, optional
            (n, 2 nq): filled with the pre-impact states (q, dq) of the scenarios that
            struck (at their last step walked).

        Returns
        -------
        WalkBatch
        """
        theta, w = np.array(theta, float).ravel(), np.array(w, float).ravel()
        n = theta.size
        if p is None:
            p = np.zeros((n, self.n_par))
            p[:, 0] = theta
        p = np.array(p, float).reshape(n, self.n_par)
        heights = step_heights(terrain, n, steps)
        run = OutcomeRecorder(n, steps)
        alive = np.ones(n, bool)
        for k in range(steps):
            idx = np.flatnonzero(alive)
            if idx.size == 0:
                break
            run.scenario_steps += idx.size
            ahead, behind = (g[idx] for g in ground_levels(heights, k))
            thm, backwards, stalled, outside, Z, Dg = self._integrate_step(
                theta[idx], w[idx], p[idx], ahead)
            which = self._step_verdicts(run, idx, thm, backwards, stalled, outside, Z, Dg,
                                        ahead, behind, k == 0 and step_start)
            bad = which != ""
            run.fail(idx[bad], which[bad], k)
            alive[idx[bad]] = False
            ok = np.flatnonzero(~bad)
            if ok.size == 0:
                continue
            self._impact(run, idx[ok], k, steps, thm[ok], Z[0][ok, -1], Z[1, ok, -1],
                         alive, theta, w, p, ends)
        return run.batch()

    def _integrate_step(self, theta, w, p, ahead):
        """One step of m scenarios from phases theta with rates w: the strike phase thm,
        whether each goes backwards, stalls or strikes outside the phase range, and the
        nodes (w, t) Z (2, m, nodes + 1) with their diagnostics from the start on."""
        direction = self.direction
        lo, hi = self.vmap.vc.theta_range
        m_ = theta.size
        thm = self._strike_phase(ahead, p)
        hs = (thm - theta) / self.nodes
        with np.errstate(invalid="ignore"):
            backwards = ~(w * direction > 0)
            stalled = backwards | ~(hs * direction > 0)
            outside = ~((thm >= lo) & (thm <= hi)) & np.isfinite(thm)
        hs = np.where(stalled | outside, 0.0, hs)
        z0 = np.vstack([w, np.zeros(m_)])
        _, _, D0 = self._nodes(z0, theta, np.zeros(m_), p, 1)
        Z, TH, Dg = self._nodes(z0, theta, hs, p, self.nodes)
        Z = np.concatenate([z0[:, :, None], Z], axis=2)
        Dg = np.concatenate([D0, Dg], axis=2)
        return thm, backwards, stalled, outside, Z, Dg

    def _step_verdicts(self, run, idx, thm, backwards, stalled, outside, Z, Dg, ahead,
                       behind, first_step):
        """Every node checked (the margins tracked in ``run``), then the step's start
        (``first_step``), its phase and its strike: per scenario the first failure
        ('' none)."""
        S, direction = self.schema, self.direction
        m_ = idx.size
        ws = Z[0]
        rows = S.rows(Dg, np.all(np.isfinite(Z), axis=0))
        zs = rows["zsw"]
        zprev = np.concatenate([zs[:, :1], zs[:, :-1]], axis=1)
        masks = node_violations(rows, self.limits, self.den_scale,
                                np.sign(rows["den"][:, :1]), zprev,
                                (ahead[:, None], behind[:, None]))
        masks["no_impact"] = rows["finite"] & ~(ws * direction > 0)   # stalls, falls back
        first, which = first_violation(masks)
        # a NaN phase rate is a stall (xi = w^2 < 0 past the turn): no impact
        stall = ~np.isfinite(ws[np.arange(m_), np.minimum(first, self.nodes)])
        which = np.where((which == "diverged") & stall, "no_impact", which)
        run.track(idx, S.row(Dg, "u"), S.row(Dg, "Fx"), S.row(Dg, "Fz"),
                  np.arange(self.nodes + 1)[None, :]
                  < np.minimum(first + 1, self.nodes + 1)[:, None])
        if first_step:
            which = np.where(which == "", start_violation(zs[:, 0], self.limits, behind),
                             which)
            which = np.where(backwards & (which == ""), "out_of_range", which)
        which = np.where(outside & (which == ""), "out_of_range", which)
        which = np.where(stalled & (which == ""), "no_impact", which)
        which = np.where(~np.isfinite(thm) & (which == ""), "no_impact", which)
        which = np.where((which == "") & ~(rows["xsw"][:, -1] > self.model.scuff_zone),
                         "no_impact", which)
        which = np.where(which == "", strike_violation(rows["dzsw"][:, -1]), which)
        with np.errstate(invalid="ignore"):     # as the simulator: no impact in time
            late = ~(Z[1, :, -1] <= self.options.horizon * self.gait.T)
        which = np.where((which == "") & late, "no_impact", which)
        return which

    def _impact(self, run, gi, k, steps, thm, wm, tm, alive, theta, w, p, ends=None):
        """The impacts of the scenarios gi at phases thm, rates wm, times tm: recorded
        and checked in ``run``; those that go on start the next step (``alive``,
        ``theta``, ``w`` and ``p`` updated in place)."""
        direction = self.direction
        th_p, w_p, p_p, F, vl, qu_m, dqu_m = self._strike(thm, wm, p[gi], gi, ends)
        F, vl, th_p, w_p = F.T, vl.ravel(), th_p.ravel(), w_p.ravel()
        err = np.c_[qu_m.ravel(), dqu_m.ravel()] - self.ref_T[None, :]
        run.impact(gi, k, err[:, 0], err[:, 1], tm, F)
        imp = impact_violation(F, vl, np.isfinite(w_p) & np.all(np.isfinite(F), axis=1)
                               & np.all(np.isfinite(p_p), axis=0), self.limits)
        badi = imp != ""
        run.fail(gi[badi], imp[badi], k)
        alive[gi[badi]] = False
        nxt = alive[gi] & ~(w_p * direction > 0) & (k + 1 < steps)
        run.fail(gi[nxt], "out_of_range", k + 1)
        alive[gi[nxt]] = False
        go = ~badi & ~nxt
        theta[gi[go]] = th_p[go]
        w[gi[go]] = w_p[go]
        p[gi[go]] = p_p.T[go]


@cached(maxsize=4)
def virtual_constraint_walker(gait, options: SimulationOptions | None = None,
                              nodes: int = 200, jit: bool = False) -> VirtualConstraintWalker:
    """The :class:`VirtualConstraintWalker` of a gait (memoised).

    Parameters
    ----------
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
    model = require_reference(gait).model
    return VirtualConstraintWalker(model, gait, options, nodes, jit)
