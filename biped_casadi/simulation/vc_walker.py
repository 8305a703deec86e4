"""Batched walking of virtual constraints on their hybrid zero dynamics, in the phase.

On the constraint surface (:class:`~biped_casadi.control.ConstraintSurface`) the
configuration is a function of the phase alone and the state is (theta, w = dtheta/dt);
the swing foot strikes at the phase theta^- where it reaches the ground, so a step is an
integration in theta from the start phase to theta^-, with every node checked
(:mod:`biped_casadi.simulation.validity`) and, between the nodes, the swing foot, the
stance force, the friction cone and the torques (:mod:`biped_casadi.simulation.margins`,
as the full-order simulator; the foot's strike is at theta^-, so any dip of it below the
ground between two nodes is a scuff), then the impact map.  Its outcomes are those
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
from ..numerics import FastCall, as_count, compiled, rk4_step
from ..simd import kernels
from .kernel import Diagnostics, call_batched, mapped, threads
from .margins import MarginCheck, dip_function, foot_dips
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
        self.margin, self._dense_fns = MarginCheck(self.limits, self.schema), None
        self.ref_T = gait.state_at(gait.T)
        self.direction = float(np.sign(self.vmap.theta_minus - self.vmap.theta_plus))
        self._build()
        ths = np.linspace(self.vmap.theta_plus, self.vmap.theta_minus, 801)
        self.den_scale = float(np.max(np.abs(np.array(self.vmap.curve.map(ths.size)(
            ths[None, :])[2]))))

    def _step(self, z, th, hs, p, tc):
        """One RK4 step of phase length hs from (w, t) = z at phase th (expressions): the
        next (w, t) and the torques, reaction and denominator there."""
        vm, sgn = self.vmap, self.direction

        # RK4 on (xi, t) with xi = w^2: d xi/d theta = 2 d2theta/dt2 is regular where the
        # phase rate w stalls (dw/dtheta = d2theta/dt2 / w is not, and RK4 on w can step
        # over a turning point); a stage past the turn has xi < 0, so w and t are NaN.
        def rhs(zv, c):
            wv = sgn * ca.sqrt(zv[0])
            return ca.vertcat(2 * vm.corrected_expressions(th + c * hs, wv, p, tc)[5], 1 / wv)

        zx = rk4_step(rhs, ca.vertcat(z[0]**2, z[1]), hs)
        zn = ca.vertcat(sgn * ca.sqrt(zx[0]), zx[1])
        return (zn, *self._point(th + hs, zn[0], p, tc))

    def _point(self, th, w, p, tc):
        """The configuration, velocity, torques, reaction and denominator on the corrected
        surface at phase th with rate w (expressions)."""
        m = self.model
        q, Q1, Q2, dw, den, _ = self.vmap.corrected_expressions(th, w, p, tc)
        ddq = Q1 * (w * dw) + Q2 * w**2
        dq = Q1 * w
        u = (ca.mtimes(m.D(q), ddq) + m.H(q, dq))[1:]
        Fx, Fz = m.ground_reaction_acc(q, dq, ddq)
        return q, dq, u, Fx, Fz, den

    def _build(self):
        m = self.model
        th, w, t, hs = ca.SX.sym("theta"), ca.SX.sym("w"), ca.SX.sym("t"), ca.SX.sym("h")
        p = ca.SX.sym("p", self.n_par)
        # the rejoin phase is an input: the compiled nodes hold no number of the gait
        # but its constraints' spline (CasADi's code, compiled apart), so the gaits of a
        # robot share their node's machine code (biped_casadi.simd)
        tc = ca.SX.sym("t_c")
        self.t_c = rejoin_phase(self.vmap.vc)
        z = ca.vertcat(w, t)
        zn, q, dq, u, Fx, Fz, den = self._step(z, th, hs, p, tc)
        thn = th + hs
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
            st = self._integrate_step(theta[idx], w[idx], p[idx], ahead)
            st.update(k=k, ahead=ahead, behind=behind)
            which, message = self._step_verdicts(run, idx, st, k == 0 and step_start)
            bad = which != ""
            run.fail(idx[bad], which[bad], k, message[bad])
            alive[idx[bad]] = False
            ok = np.flatnonzero(~bad)
            if ok.size == 0:
                continue
            Z = st["Z"]
            self._impact(run, idx[ok], k, steps, st["thm"][ok], Z[0][ok, -1], Z[1, ok, -1],
                         alive, theta, w, p, ends)
        return run.batch()

    def _integrate_step(self, theta, w, p, ahead) -> dict:
        """One step of m scenarios from phases theta with rates w (step constants p): the
        strike phase thm, whether each goes backwards, stalls or strikes outside the phase
        range, the phase step hs (0 where it cannot be taken), and the nodes (w, t) Z
        (2, m, nodes + 1) with their diagnostics Dg from the start on."""
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
        return dict(thm=thm, backwards=backwards, stalled=stalled, outside=outside, hs=hs,
                    theta=theta, p=p, Z=Z, Dg=Dg)

    def _step_verdicts(self, run, idx, st, first_step):
        """Every node checked, then between the nodes (the margins tracked in ``run``),
        then the step's start (``first_step``), its phase and its strike: per scenario
        the first failure ('' none) and its message."""
        S, direction, Z = self.schema, self.direction, st["Z"]
        m_ = idx.size
        ws = Z[0]
        rows = S.rows(st["Dg"], np.all(np.isfinite(Z), axis=0))
        zs = rows["zsw"]
        zprev = np.concatenate([zs[:, :1], zs[:, :-1]], axis=1)
        masks = node_violations(rows, self.limits, self.den_scale,
                                np.sign(rows["den"][:, :1]), zprev,
                                (st["ahead"][:, None], st["behind"][:, None]))
        masks["no_impact"] = rows["finite"] & ~(ws * direction > 0)   # stalls, falls back
        first, which = first_violation(masks)
        # a NaN phase rate is a stall (xi = w^2 < 0 past the turn): no impact
        stall = ~np.isfinite(ws[np.arange(m_), np.minimum(first, self.nodes)])
        which = np.where((which == "diverged") & stall, "no_impact", which)
        start = start_violation(zs[:, 0], self.limits, st["behind"]) if first_step else \
            np.full(m_, "", dtype=object)
        message = self._between(run, idx, st, rows, np.where(
            (start != "") | (st["hs"] == 0), 0, np.minimum(first, self.nodes)), first, which)
        run.track(idx, S.row(st["Dg"], "u"), S.row(st["Dg"], "Fx"), S.row(st["Dg"], "Fz"),
                  np.arange(self.nodes + 1)[None, :]
                  < np.minimum(first + 1, self.nodes + 1)[:, None])
        if first_step:
            which = np.where(which == "", start, which)
            which = np.where(st["backwards"] & (which == ""), "out_of_range", which)
        which = np.where(st["outside"] & (which == ""), "out_of_range", which)
        which = np.where(st["stalled"] & (which == ""), "no_impact", which)
        which = np.where(~np.isfinite(st["thm"]) & (which == ""), "no_impact", which)
        which = np.where((which == "") & ~(rows["xsw"][:, -1] > self.model.scuff_zone),
                         "no_impact", which)
        which = np.where(which == "", strike_violation(rows["dzsw"][:, -1]), which)
        with np.errstate(invalid="ignore"):     # as the simulator: no impact in time
            late = ~(Z[1, :, -1] <= self.options.horizon * self.gait.T)
        which = np.where((which == "") & late, "no_impact", which)
        return which, message

    def _between(self, run, idx, st, rows, stop, first, which):
        """The margins and the swing foot between the nodes of each scenario's first
        ``stop`` steps (:mod:`~biped_casadi.simulation.margins`; every dip of the foot
        below the ground is a scuff: this walker's strike is at theta^-): a dip there
        ends the run before its nodes' failure (``first``, ``which`` updated, the state
        at the dip tracked in ``run``).  Returns the messages ('' none)."""
        Z, hs, sgn, k = st["Z"], st["hs"], self.direction, st["k"]
        message = np.full(idx.size, "", dtype=object)

        def between(*a):             # built at first use
            return self._dense()[0](*a)

        def node(i, j):              # step j's first node of scenario i: (z, theta, p)
            return Z[:, i, j], st["theta"][i] + j * hs[i], np.r_[st["p"][i], self.t_c]

        feet = foot_dips(lambda *a: self._dense()[1](*a), np.abs(hs), node,
                         rows["zsw"][:, :-1], rows["dzsw"][:, :-1], rows["dzsw"][:, 1:], stop,
                         (st["ahead"], st["behind"]), np.inf, self.limits,
                         np.diff(Z[1], axis=1))      # the steps' durations
        for i, got in feet.items():
            stop[i] = got[0]         # the margins before the foot's dip
        R = self.margin.rows(st["Dg"])
        near = np.flatnonzero(self.margin.near(R) & (stop > 0))
        dips = {int(near[i]): got for i, got in self.margin.first_dips(
            between, self.margin.of_rows(R[:, near]), self.nodes,
            lambda i, j: (*node(near[i], j)[:2], abs(hs[near[i]]), node(near[i], j)[2]),
            stop[near]).items()} if near.size else {}
        for i, (j, eta, status) in {**{i: (f[0], f[2], "scuffed") for i, f in feet.items()},
                                    **dips}.items():
            zj, thj, _ = node(i, j)
            D = np.array(self.node(zj, thj, sgn * eta, st["p"][i])[2])
            run.track(idx[[i]], *(self.schema.row(D, r)[..., None] for r in ("u", "Fx", "Fz")))
            first[i], which[i] = j, status
            message[i] = f"step {k + 1}: " + self.margin.message(status, D, self.den_scale)
        return message

    def _dense(self):
        """The margins (:class:`~biped_casadi.simulation.margins.MarginCheck`) and the
        swing foot at the end of the RK4 step of phase length sgn eta from a node
        ((w, t), theta; p: the step constants and the rejoin phase), with their rates in
        eta; built at first use, then shared by every batch."""
        if self._dense_fns is None:
            z, th, eta = ca.SX.sym("z", 2), ca.SX.sym("theta"), ca.SX.sym("eta")
            pp = ca.SX.sym("p", self.n_par + 1)
            hs = self.direction * eta
            zn = self._step(z, th, hs, pp[:-1], pp[-1])[0]
            rk4 = ca.Function("vc_rk4", [z, th, eta, pp], [zn, th + hs])

            def margins(Z, thv, p):
                return self.margin.values(*self._point(thv, Z[0], p[:-1], p[-1])[2:5], lib=ca)

            fs = [self.margin.function(rk4, margins), dip_function(
                rk4, lambda Z, thv, p: self.model.swing_foot(self._point(thv, Z[0], p[:-1],
                                                                          p[-1])[0]))]
            self._dense_fns = tuple(FastCall(f) for f in fs)
        return self._dense_fns

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
