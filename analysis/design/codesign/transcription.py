"""Transcription of the robust co-design: perturbation scenarios of the hybrid
zero dynamics walked step by step with the walker's own rule, as smooth NLP functions of
the design (M1, the rejoin time of v_c), the perturbation scale s and, optionally, the
gait (its Bezier coefficients alpha, T and the unactuated start state).

Rule.  Inside a step the closed loop of :mod:`biped_casadi.control.zero_dynamics` is
integrated by classical RK4 on the fixed grid tau_k = k T / N (N = ``nodes_per_T``),
exactly as :class:`~biped_casadi.simulation.tv_walker.ZeroDynamicsWalker` does, followed
by one partial RK4 step of length eta h (the reference state integrated alongside) that
ends on the strike z_sw = 0.  The reference's joins (T, and (1 + c) T for the ramp
continuation) lie on grid nodes, so no RK4 step straddles them, and eta in [0, 1) keeps
the partial step inside one node interval: with the number of full nodes fixed, every
function is smooth.  The NLP itself (:class:`~analysis.design.codesign.reduced.Reduced`)
walks every scenario from the design at each evaluation (single shooting per scenario)
and condenses the steps' sensitivities into the exact Jacobian in the design; the
number of full nodes of a step is the walker's own (the strike found as it finds it).

Derivatives.  Forward sensitivities: one compiled SX Function per RK4 node gives the
node's next state, its diagnostics (torques, stance reaction, swing foot, eq. 24
denominator) and their Jacobians in the step's columns (its start, M1, the rejoin, and
the gait's variables through the tabulated reference and its own sensitivities); the
partial step, the impact (eq. 2-3), the reset of v_c (eq. 17) and the scenario starts
are SX Functions differentiated by AD.  IPOPT gets the exact constraint Jacobian; the
Hessian is approximated (L-BFGS).  ``tests/test_codesign.py`` checks the Jacobian
against central differences.

Constraints per scenario-step (the walker's validity, :mod:`biped_casadi.simulation.validity`,
with margins): torque, stance normal force, friction cone and the eq. 24 denominator at
every node (aggregated per chunk of nodes by a Kreisselmeier-Steinhauser bound, which
is conservative), the swing foot above the ground at every node before the strike, the
strike (z_sw = 0, moving down, in front of the stance foot), the impact impulse normal
and inside the cone, lift-off of the old stance foot, continuity into the next step.
The gait, when free, carries the constraints of :mod:`gait_opt.transcription` on its own
nominal step (periodic through the impact, on the ground at T, speed, step length,
strike and lift-off speeds, impulse cone, torque, contact, friction, clearance, knee
limits), evaluated on the same reference table.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .functions import (
    TranscriptionSettings,
    _accumulated,
    _chunked,
    _node_functions,
    _reference_functions,
    _step_functions,
)


# ------------------------------------------------------------------ the transcription
@dataclass
class _Rows:
    """Constraint rows built by one evaluation: values, bounds, Jacobian triplets."""

    g: list = field(default_factory=list)
    lo: list = field(default_factory=list)
    hi: list = field(default_factory=list)
    rows: list = field(default_factory=list)
    cols: list = field(default_factory=list)
    vals: list = field(default_factory=list)
    names: list = field(default_factory=list)
    n: int = 0

    def add(self, value, jac, cols, lo, hi, name):
        """Rows ``value`` (m,) with dense Jacobian ``jac`` (m, len(cols)) on ``cols``."""
        value = np.atleast_1d(np.asarray(value, float))
        m = value.size
        jac = np.asarray(jac, float).reshape(m, len(cols))
        r = self.n + np.arange(m)
        self.g.append(value)
        self.lo.append(np.broadcast_to(lo, (m,)).astype(float))
        self.hi.append(np.broadcast_to(hi, (m,)).astype(float))
        self.rows.append(np.repeat(r, len(cols)))
        self.cols.append(np.tile(np.asarray(cols, int), m))
        self.vals.append(jac.ravel())
        self.names += [name] * m if isinstance(name, str) else list(name)
        self.n += m

    def stack(self):
        cat = np.concatenate
        return (cat(self.g), cat(self.lo), cat(self.hi), cat(self.rows), cat(self.cols),
                cat(self.vals))


class GaitTable:
    """A gait's reference tabulated on the half-grid of the walker's rule, with its
    sensitivities in the gait's variables G = (alpha, T, r0) when the gait is free, and
    the gait's own constraints (those of :mod:`gait_opt.transcription`) on its nominal
    step: what :class:`Transcription` and the gait move
    (:mod:`analysis.design.codesign.gait_move`) share.

    Parameters
    ----------
    model : BipedModel
        The robot.
    gait : Gait
        The gait (fixed) or the gait to start from (free); its options give the Bezier
        degree, the continuation past T and the gait's own constraints.
    settings : TranscriptionSettings, optional
        The rule (nodes per T, horizon) and the torque limit (its defaults filled in for
        the robot: :meth:`TranscriptionSettings.for_model`).
    free_gait : bool
        Whether G is variable (the first ``nG`` entries of the decision vector).
    """

    #: nodes per compiled call
    CHUNK = 8

    def __init__(self, model, gait, settings: TranscriptionSettings | None = None,
                 free_gait: bool = True):
        self.model, self.gait = model, gait
        self.st = st = (settings or TranscriptionSettings()).for_model(model)
        self.free = bool(free_gait)
        o = gait.options
        self.degree, self.cont, self.shape = o.bezier_degree, o.continuation, o.continuation_shape
        self.nu, self.nq = model.nu, model.nq
        self.na = self.nu * (self.degree + 1)
        self.nG = self.na + 3 if self.free else 0
        self.N = st.nodes_per_T
        self.n_max = int(math.ceil(st.horizon * self.N))
        if self.free:
            self.ref_step, self.ref_point, self.boundary = _reference_functions(
                model, self.degree, self.cont, self.shape)
        self.i_G = np.arange(self.nG)

    def gait_vector(self, gait):
        """G = (vec alpha, T, r0) of a gait (column-major alpha, as CasADi reshapes)."""
        return np.r_[gait.alpha.ravel(order="F"), gait.T, gait.x0]

    def gait_of(self, w):
        """(alpha (nu, M+1), T, r0) of the decision vector w (the fixed gait's if fixed)."""
        if not self.free:
            return self.gait.alpha, self.gait.T, self.gait.x0
        G = np.asarray(w, float)[self.i_G]
        alpha = G[:self.na].reshape(self.nu, self.degree + 1, order="F")
        return alpha, float(G[self.na]), G[self.na + 1:]

    def gait_bounds(self):
        """(lb, ub) of G: the Bezier coefficients within +-pi and the knee limits, T within
        the step-time bounds, r0 free."""
        o = self.gait.options
        lb, ub = np.full(self.nG, -np.inf), np.full(self.nG, np.inf)
        a_lb = np.full((self.nu, self.degree + 1), -np.pi)
        a_ub = np.full((self.nu, self.degree + 1), np.pi)
        for i in self.model.stance_knees:
            a_ub[i - 1, :] = o.stance_knee_max
        for i in self.model.swing_knees:
            a_lb[i - 1, :] = o.swing_knee_min
        lb[:self.na], ub[:self.na] = a_lb.ravel(order="F"), a_ub.ravel(order="F")
        lb[self.na], ub[self.na] = o.step_time_bounds
        return lb, ub

    # ----------------------------------------------------------------- reference table
    def table(self, w):
        """The reference at the half-grid s_i = i / (2N), i = 0..2 n_max + 2: R (15, n),
        dR/dG (15, nG, n), the reference state r (2, n) and dr/dG (2, nG, n), and the
        nominal diagnostics for the gait's own constraints (free gait)."""
        alpha, T, r0 = self.gait_of(w)
        n = 2 * (self.n_max + self.CHUNK) + 3
        s = np.arange(n) / (2 * self.N)
        if not self.free:
            key = ("fixed",)
            if getattr(self, "_table_key", None) != key:
                q, dq, ddq = self.gait.evaluate(np.minimum(s * T, self.gait.t_max))
                R = np.vstack([q, dq, ddq])
                self._table = dict(R=R, dR=np.zeros((3 * self.nq, 0, n)), r=R[[0, self.nq]],
                                   dr=np.zeros((2, 0, n)))
                self._table_key = key
            return self._table
        key = tuple(w[self.i_G])
        if getattr(self, "_table_key", None) == key:
            return self._table
        nG = self.nG
        a = w[self.i_G][:self.na]
        acc = _accumulated(self.ref_step, n - 1)
        X, SS = acc(r0, np.hstack([np.zeros((2, self.na + 1)), np.eye(2)]),
                    s[None, :-1], 1.0 / (2 * self.N), a, T)
        r = np.hstack([r0[:, None], np.array(X)])
        dr = np.concatenate([np.hstack([np.zeros((2, self.na + 1)), np.eye(2)])[:, :, None],
                             np.array(SS).reshape(2, n - 1, nG).transpose(0, 2, 1)], axis=2)
        out, J = self.ref_point.map(n)(np.vstack([r, np.repeat(np.r_[a, T][:, None], n, 1)]),
                                       s[None, :])
        out, J = np.array(out), np.array(J).reshape(out.shape[0], n, -1).transpose(0, 2, 1)
        # d out / dG = J_r dr + [J_alpha, J_T, 0]
        dout = np.einsum("oan,agn->ogn", J[:, :2], dr)
        dout[:, :self.na + 1] += J[:, 2:]
        nq = self.nq
        self._table = dict(R=out[:3 * nq], dR=dout[:3 * nq], r=r, dr=dr,
                           nominal=out[3 * nq:], dnominal=dout[3 * nq:])
        self._table_key = key
        return self._table

    def _gait_rows(self, rows, w, tab):
        """The gait's own constraints (gait_opt.transcription), on its nominal step."""
        o = self.gait.options
        nq, nu, na = self.nq, self.nu, self.na
        alpha, T, r0 = self.gait_of(w)
        n1 = 2 * self.N
        r1, dr1 = tab["r"][:, n1], tab["dr"][:, :, n1]
        out, J = self.boundary(np.r_[r1, w[self.i_G][:na], T, r0])
        out, J = np.array(out).ravel(), np.array(J)
        dG = J[:, :2] @ dr1
        dG[:, :na + 1] += J[:, 2:3 + na]
        dG[:, na + 1:] += J[:, 3 + na:]
        G = self.i_G
        rows.add(out[:2 * nq], dG[:2 * nq], G, 0.0, 0.0, "gait periodicity")
        rows.add(out[2 * nq], dG[2 * nq], G, 0.0, 0.0, "gait swing foot on the ground at T")
        xe, dxe = out[2 * nq + 1], dG[2 * nq + 1]
        dT = np.zeros(self.nG)
        dT[na] = 1.0
        rows.add(xe - o.speed * T, dxe - o.speed * dT, G, 0.0, 0.0, "gait speed")
        rows.add(xe, dxe, G, *o.step_length_bounds, "gait step length")
        rows.add(out[2 * nq + 2], dG[2 * nq + 2], G, -np.inf, -o.min_strike_speed,
                 "gait strike velocity")
        rows.add(out[2 * nq + 3], dG[2 * nq + 3], G, o.min_liftoff_speed, np.inf,
                 "gait lift-off velocity")
        F, dF = out[2 * nq + 4:], dG[2 * nq + 4:]
        mu_i = o.impulse_mu
        rows.add(np.r_[F[1], mu_i * F[1] - F[0], mu_i * F[1] + F[0]],
                 np.vstack([dF[1], mu_i * dF[1] - dF[0], mu_i * dF[1] + dF[0]]), G, 0.0, np.inf,
                 "gait impact impulse cone")
        # path on the nominal step, at the grid nodes inside (0, T)
        idx = 2 * np.arange(1, self.N)
        nom, dnom = tab["nominal"][:, idx], tab["dnominal"][:, :, idx]
        s = idx / (2 * self.N)
        U = self.torque_bound(idx.size)
        u, du = nom[:nu], dnom[:nu]
        rows.add(u.T.ravel(), du.transpose(2, 0, 1).reshape(-1, self.nG), G, -U, U,
                 "gait torque limit")
        Fx, Fz, dFx, dFz = nom[nu], nom[nu + 1], dnom[nu], dnom[nu + 1]
        rows.add(Fz, dFz.T, G, o.min_normal_force, np.inf, "gait normal force")
        rows.add(np.r_[o.mu * Fz - Fx, o.mu * Fz + Fx], np.vstack([(o.mu * dFz - dFx).T,
                                                                  (o.mu * dFz + dFx).T]),
                 G, 0.0, np.inf, "gait friction cone")
        zsw, dzsw = nom[nu + 3], dnom[nu + 3]
        rows.add(zsw - o.clearance * 4 * s * (1 - s), dzsw.T, G, 0.0, np.inf,
                 "gait swing-foot clearance")

    def torque_bound(self, nodes: int):
        """The gait's torque bound on the rows of ``nodes`` nodes' torques, node by node
        (``u.T.ravel()``): its options' limit (else the settings'), one number or each
        torque's (tiled), N m."""
        U = self.gait.options.torque_limit or self.st.torque_limit
        return U if np.ndim(U) == 0 else np.tile(np.asarray(U, float), nodes)


class Transcription(GaitTable):
    """Scenarios of the hybrid zero dynamics as NLP functions (module docstring).

    Decision vector w = (G, M1, rejoin, s, then per scenario and step (q_u, dq_u, y_i,
    dy_i, eta)); G = (alpha, T, r0) only when the gait is free.

    Parameters
    ----------
    model : BipedModel
        The robot.
    gait : Gait
        The gait (fixed) or the gait to start from (free); its options give the Bezier
        degree, the continuation past T and, when free, the gait's own constraints.
    directions : numpy.ndarray
        (K, 2 nq) perturbation directions of the scenarios.
    steps : int
        Steps per scenario.
    free_gait : bool
        Whether alpha, T and r0 are decision variables.
    settings : TranscriptionSettings, optional
        Rule and margins.
    """

    def __init__(self, model, gait, directions, steps: int, free_gait: bool,
                 settings: TranscriptionSettings | None = None):
        super().__init__(model, gait, settings, free_gait)
        st, nu = self.st, self.nu
        self.dirs = np.atleast_2d(np.asarray(directions, float))
        self.K, self.S = len(self.dirs), int(steps)
        self.nc = 2 + 3 * nu + 1 + self.nG          # columns of a scenario-step
        self.nl = 2 + 2 * nu                          # step start variables
        self.threads = int(st.threads)
        self.node = _node_functions(model, self.nG)
        self.start_fn, self.diag0_fn, self.last_fn, self.last_value, self.rows = \
            _step_functions(model, self.degree, self.cont, self.shape, self.free)
        # layout of w
        self.i_M1 = self.nG + np.arange(nu)
        self.i_rejoin = self.nG + nu
        self.i_s = self.nG + nu + 1
        self.n_design = self.nG + nu + 2
        #: the decision-dependent sign and scale of the eq. 24 denominator (set per solve
        #: from the starting design, as the walker sets them per design)
        self.den_sign, self.den_scale = 1.0, 1.0
        self.mg = float(model.description.total_mass * model.description.gravity)

    # ----------------------------------------------------------------- layout helpers
    def unpack(self, w):
        """(alpha (nu, M+1), T, r0, M1, rejoin, s) of w (the fixed gait's where fixed)."""
        w = np.asarray(w, float)
        alpha, T, r0 = self.gait_of(w)
        return alpha, T, r0, w[self.i_M1], float(w[self.i_rejoin]), float(w[self.i_s])

    def R3(self, tab, k0, n):
        """(R3 (45, n), dR3 (45, nG, n) or None) of nodes k0..k0+n-1: the reference at
        each node's three RK4 stages and its sensitivity in the gait (free gait)."""
        idx = 2 * (k0 + np.arange(n))
        R = tab["R"]
        R3 = np.vstack([R[:, idx], R[:, idx + 1], R[:, idx + 2]])
        if not self.free:
            return R3, None
        dR = tab["dR"]
        return R3, np.concatenate([dR[:, :, idx], dR[:, :, idx + 1], dR[:, :, idx + 2]], axis=0)

    # ----------------------------------------------------------------- one scenario-step
    def _dP(self, T, rejoin):
        nu, nc = self.nu, self.nc
        dP = np.zeros((3 * nu + 1, nc))
        dP[:nu, 2 + 2 * nu:2 + 3 * nu] = np.eye(nu)                # M1
        dP[nu, 2 + 3 * nu] = T                                       # t_c = rejoin T
        if self.free:
            dP[nu, 2 + 3 * nu + 1 + self.na] = rejoin
        dP[nu + 1:2 * nu + 1, 2:2 + nu] = np.eye(nu)               # y_i
        dP[2 * nu + 1:, 2 + nu:2 + 2 * nu] = np.eye(nu)            # dy_i
        return dP

    def nodes(self, tab, L, n, M1, rejoin, T):
        """Integrate scenario-steps from their start variables over n full nodes.

        The scenarios (rows of L) are walked together, ``CHUNK`` nodes per call, mapped
        over ``threads`` threads.

        Parameters
        ----------
        tab : dict
            The reference table (:meth:`table`).
        L : numpy.ndarray
            (m, nl) step starts (q_u, dq_u, y_i, dy_i).
        n : int
            Full nodes.
        M1 : numpy.ndarray
            (nu,) outputs.
        rejoin, T : float
            Rejoin fraction and step duration.

        Returns
        -------
        tuple
            (X (m, 2, n+1), SS (m, 2, nc, n+1), diag (m, nu+5, n+1), ddiag (m, nu+5, nc+1, n+1),
            P (m, n_par), dP): the states, their sensitivities in the step's columns, the
            diagnostics at the nodes (node 0 at tau = 0) with their sensitivities (the last
            column, eta, zero), the step parameters and their sensitivities.
        """
        nu, nc, nq, h = self.nu, self.nc, self.nq, T / self.N
        L = np.atleast_2d(L)
        m = len(L)
        P = np.hstack([np.broadcast_to(M1, (m, nu)), np.full((m, 1), rejoin * T), L[:, 2:]])
        dP = self._dP(T, rejoin)
        S0 = np.zeros((2, nc))
        S0[:, :2] = np.eye(2)
        d0, J0 = self.diag0_fn.map(m)(np.vstack([L[:, :2].T, np.repeat(tab["R"][:, :1], m, 1),
                                                  P.T]), 0.0)
        nd = self.nu + 5                                # diagnostics: u, Fx, Fz, x, z, den
        d0 = np.array(d0).T                                           # (m, nd)
        J0 = np.array(J0).reshape(nd, m, -1).transpose(1, 0, 2)       # (m, nd, 2 + 3nq + np)
        dd0 = np.zeros((m, nd, nc + 1))
        dd0[:, :, :nc] = J0[:, :, :2] @ S0 + J0[:, :, 2 + 3 * nq:] @ dP
        if self.free:
            dd0[:, :, nc - self.nG:nc] += J0[:, :, 2:2 + 3 * nq] @ tab["dR"][:, :, 0]
        X = np.zeros((m, 2, n + 1))
        SS = np.zeros((m, 2, nc, n + 1))
        diag = np.zeros((m, nd, n + 1))
        ddiag = np.zeros((m, nd, nc + 1, n + 1))
        X[:, :, 0], SS[:, :, :, 0], diag[:, :, 0], ddiag[:, :, :, 0] = L[:, :2], S0, d0, dd0
        if n > 0:
            if self.node.kernel is not None:
                self._walk_kernel(tab, X, SS, diag, ddiag, n, h, P, dP, S0)
            else:
                self._walk_chunks(tab, X, SS, diag, ddiag, n, h, P, dP, S0)
        return X, SS, diag, ddiag, P, dP

    def _dth(self, k):
        """d(tau, h)/d(columns) of nodes k: (2, nc, len(k)) (the gait's T column only)."""
        dth = np.zeros((2, self.nc, len(k)))
        if self.free:
            iT = self.nc - self.nG + self.na
            dth[0, iT], dth[1, iT] = k / self.N, 1.0 / self.N
        return dth

    def _walk_kernel(self, tab, X, SS, diag, ddiag, n, h, P, dP, S0):
        """Nodes 1..n of every scenario in one call of the node's four-lane kernel."""
        m, nc, nq = len(P), self.nc, self.nq
        k = np.arange(n)
        R3, dR3 = self.R3(tab, 0, n)
        per_node = [R3] if dR3 is None else [   # dR3: column-major (45, nG) per node
            R3, dR3.transpose(1, 0, 2).reshape(9 * nq * self.nG, n)]
        x = X[:, :, 0].T
        S = np.repeat(S0.T.reshape(-1, 1), m, 1)            # column-major (2, nc) each
        Xn, Sn, Dg, DD = self.node.kernel(
            x, S, (k * h)[None, :], np.array([h]), *per_node, P.T, dP.T.ravel(),
            self._dth(k).transpose(1, 0, 2).reshape(2 * nc, n), K=n, threads=self.threads)
        X[:, :, 1:] = Xn.transpose(1, 0, 2)
        SS[:, :, :, 1:] = Sn.reshape(nc, 2, m, n).transpose(2, 1, 0, 3)
        diag[:, :, 1:] = Dg.transpose(1, 0, 2)
        ddiag[:, :, :nc, 1:] = DD.reshape(nc, self.nu + 5, m, n).transpose(2, 1, 0, 3)

    def _walk_chunks(self, tab, X, SS, diag, ddiag, n, h, P, dP, S0):
        """Nodes 1..n of every scenario, ``CHUNK`` nodes per call of the scalar node
        mapped over the scenarios (where no kernel could be built)."""
        m, nc, C = len(P), self.nc, self.CHUNK
        x, S = X[:, :, 0].T.copy(), np.tile(S0, m)
        fn = _chunked(self.node.scalar, C, m, self.threads)
        Pm = np.repeat(P.T, C, axis=1) if m == 1 else np.hstack(
            [np.repeat(P[i][:, None], C, 1) for i in range(m)])
        for k0 in range(0, n, C):
            k = k0 + np.arange(C)
            R3, dR3 = self.R3(tab, k0, C)
            if dR3 is not None:                 # 45 x (C nG), node-major
                dR3 = dR3.transpose(0, 2, 1).reshape(9 * self.nq, -1)
            dth = self._dth(k).transpose(0, 2, 1).reshape(2, nc * C)
            args = [x, S, (k * h)[None, :], np.full((1, C), h), R3] + (
                [dR3] if self.free else []) + [Pm, np.tile(dP, C), dth]
            Xn, Sn, Dg, DD = (np.array(v) for v in fn(*args))
            cnt = min(C, n - k0)
            sl = slice(k0 + 1, k0 + 1 + cnt)
            X[:, :, sl] = Xn.reshape(2, m, C).transpose(1, 0, 2)[:, :, :cnt]
            SS[:, :, :, sl] = Sn.reshape(2, m, C, nc).transpose(1, 0, 3, 2)[..., :cnt]
            nd = self.nu + 5
            diag[:, :, sl] = Dg.reshape(nd, m, C).transpose(1, 0, 2)[:, :, :cnt]
            ddiag[:, :, :nc, sl] = DD.reshape(nd, m, C, nc).transpose(1, 0, 3, 2)[..., :cnt]
            x = Xn.reshape(2, m, C)[:, :, -1]
            S = Sn.reshape(2, m, C, nc)[:, :, -1, :].transpose(0, 1, 2).reshape(2, m * nc)

    def _last_input(self, tab, x, n, eta, P, T, alpha):
        return np.r_[x, tab["r"][:, 2 * n], n * T / self.N, eta * T / self.N, P,
                     np.asarray(alpha).ravel(order="F"), T, tab["R"][:, 0]]

    def finish(self, tab, x, S, n, eta, P, dP, T, alpha):
        """The partial step of length eta h from node n, the strike, the impact and the
        next step's start: (outputs, Jacobian in the step's columns and eta)."""
        nc, h = self.nc, T / self.N
        out, J = self.last_fn(self._last_input(tab, x, n, eta, P, T, alpha))
        out, J = np.array(out).ravel(), np.array(J)
        m = 2 + 2 + 1 + 1 + P.size + self.na + 1 + 3 * self.nq
        Din = np.zeros((m, nc + 1))
        Din[0:2, :nc] = S
        Din[5, nc] = h
        o = 6
        Din[o:o + P.size, :nc] = dP
        o += P.size
        if self.free:
            g0 = nc - self.nG
            Din[2:4, g0:nc] = tab["dr"][:, :, 2 * n]
            Din[4, g0 + self.na] = n / self.N
            Din[5, g0 + self.na] = eta / self.N
            Din[o:o + self.na, g0:g0 + self.na] = np.eye(self.na)
            Din[o + self.na, g0 + self.na] = 1.0
            Din[o + self.na + 1:, g0:nc] = tab["dR"][:, :, 0]
        return out, J @ Din

    def _with_last(self, diag, ddiag, out, Jl):
        r = self.rows
        ide = np.r_[np.arange(r["u"].start, r["u"].stop), r["Fx"], r["Fz"], r["xsw"], r["zsw"],
                    r["den"]]
        return (np.hstack([diag, out[ide][:, None]]),
                np.concatenate([ddiag, Jl[ide][:, :, None]], axis=2), out, Jl)

    def strike_in(self, tab, X, diag, n_full, P, T, alpha):
        """The bracket and eta of the first strike (None when there is none): the swing
        foot crossing the ground downward in front of the stance foot between two nodes,
        then the root of z_sw in the partial step (safeguarded secant)."""
        z, xs = diag[self.nu + 3, :n_full + 1], diag[self.nu + 2, :n_full + 1]
        cross = np.flatnonzero((z[:-1] >= 0) & (z[1:] < 0) & (xs[1:] > 0))
        cross = cross[cross >= 1]
        if not cross.size:
            return None
        n = int(cross[0])
        a, b, za, zb = 0.0, 1.0, z[n], z[n + 1]
        eta = a - za * (b - a) / (zb - za)
        for _ in range(40):
            ze = float(self.last_value(self._last_input(tab, X[:, n], n, eta, P, T, alpha)))
            if abs(ze) < 1e-14:
                break
            if ze > 0:
                a, za = eta, ze
            else:
                b, zb = eta, ze
            eta_n = a - za * (b - a) / (zb - za)
            if not a < eta_n < b:
                eta_n = 0.5 * (a + b)
            if abs(eta_n - eta) < 1e-15:
                break
            eta = eta_n
        return n, eta

    # ----------------------------------------------------------------- bounds, start
    def bounds(self, M1_box: float = 40.0):
        """Bounds of the design: the gait's (T, knee limits), M1 box, rejoin, s."""
        lb, ub = np.full(self.n_design, -np.inf), np.full(self.n_design, np.inf)
        if self.free:
            lb[self.i_G], ub[self.i_G] = self.gait_bounds()
        lb[self.i_M1], ub[self.i_M1] = -M1_box, M1_box
        lb[self.i_rejoin], ub[self.i_rejoin] = 0.5, 0.75
        lb[self.i_s], ub[self.i_s] = 0.0, 3.0
        return lb, ub

