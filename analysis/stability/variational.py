"""A^z for many M1 at once: the variational equation of the zero dynamics along the
periodic orbit, vectorised over M1 (numpy).

At the fixed point the closed loop follows the reference exactly for every M1, so the
linearisation of eq. (19) about it has coefficients that are rational in M1 with
M1-independent factors taken (by AD) along q^d(t):

    (D11 - D12 M1) d(ddq_u) = w . dq - h_dq . d(dq) - D12 d(ddv),
    w = -(G_D12' ddq_a^d) - grad_q H1 - ddq_u^d grad_q D11,

where G_D12 = dD12/dq, h_dq = dH1/d(dq), dq = M_T d(q_u) + (0, dv_c), M_T = (1, -M1).
(M1 cancels from w because ddv^d - M1 ddq_u^d = ddq_a^d.)  The impact time varies by
d tau = -(grad z_sw . M_T d q_u) / (dz_sw/dt) (implicit-function theorem), the impact map
is linearised by AD at (q^d(T), dq^d(T)), and v_c enters the post-impact segment as a
forcing linear in (y_i, dy_i).  Both segments use RK4 on the same grids as
:class:`analysis.stability.poincare.PoincareMap`, whose full AD Jacobian this reproduces to
integration accuracy (tests/test_poincare.py).

The result is one SX Function ``A_fn(M1) -> A^z`` (the tables are numbers inside it):
cheap to evaluate (mapped over threads for sweeps) and differentiable in M1 to any
order, which the output-selection NLP uses.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from biped_casadi.caching import cached
from biped_casadi.numerics import as_count, as_number, rk4_step
from biped_casadi.control import require_reference, require_same_robot
from biped_casadi.control.output_law import check_rejoin, outputs
from biped_casadi.control.zero_dynamics import zero_dynamics

__all__ = ["VariationalJacobian", "variational_jacobian"]


def _rk4_times(t0, t1, n):
    h = (t1 - t0) / n
    t = t0 + h * np.arange(n)
    return h, np.stack([t, t + h / 2, t + h], axis=1)       # (n, 3): t, mid, end


class VariationalJacobian:
    """Precomputes the M1-independent coefficient tables once per gait.

    Parameters
    ----------
    model : BipedModel
    gait : Reference
    tau_s : float
        Section time (0.75 T).
    n_pre, n_post : int
        RK4 steps before and after the impact (as the full map).
    rejoin : float
        Rejoin time of v_c as a fraction of T.
    """

    def __init__(self, model, gait, tau_s: float, n_pre: int, n_post: int,
                 rejoin: float = 0.5):
        require_same_robot(model, require_reference(gait))
        self.model, self.gait = model, gait
        self.T = T = gait.T
        self.t_c = check_rejoin(rejoin) * T
        self.n_pre, self.n_post = as_count(n_pre, "n_pre"), as_count(n_post, "n_post")
        if not 0 < as_number(tau_s, "tau_s") < T:
            raise ValueError(f"tau_s (the section time) must lie in (0, T = {T:.6g}), "
                             f"got {tau_s!r}")
        self._zd = zero_dynamics(model)
        q, dq = model.q_sym, model.dq_sym
        self.h_pre, self.t_pre = _rk4_times(tau_s, T, n_pre)
        self.h_post, self.t_post = _rk4_times(0.0, tau_s, n_post)
        self.pre = self._table(self.t_pre)
        self.post = self._table(self.t_post, with_vc=True)

        # impact: gradient of the guard, strike speed, linearised impact map at T
        qT, dqT, ddqT = gait.evaluate(np.array([T]))
        qT, dqT, ddqT = qT[:, 0], dqT[:, 0], ddqT[:, 0]
        zsw = model.swing_foot(q)[1]
        self.grad_z = np.array(ca.Function("gz", [q], [ca.gradient(zsw, q)])(qT)).ravel()
        self.zdot = float(self.grad_z @ dqT)
        qp, dqp = model.impact(q, dq)
        JD = ca.Function("JD", [q, dq], [ca.jacobian(ca.vertcat(qp, dqp), ca.vertcat(q, dq))])
        self.J_impact = np.array(JD(qT, dqT))                 # 2 nq x 2 nq
        self.dqT, self.ddqT = dqT, ddqT
        self._fns = None

    @property
    def A_fn(self) -> ca.Function:
        """A^z as one SX Function of M1, built at first use.

        The NLPs differentiate it; numbers alone come from the compiled kernels
        (:meth:`jacobians`).
        """
        if self._fns is None:
            self._build()
        return self._fns[0]

    @property
    def trace_det(self) -> ca.Function:
        """(trace, det) of A^z as one SX Function of M1 (built at first use)."""
        if self._fns is None:
            self._build()
        return self._fns[1]

    def _table(self, times, with_vc=False):
        """The linearisation's factors at every RK4 stage time (stage-major: t, mid, end
        per step) and, after the impact, the correction's basis there."""
        t = times.ravel()
        lin = self._zd.linearisation(*self.gait.evaluate(t))
        basis = self._zd.correction_basis(t, self.t_c) if with_vc else None
        return lin, basis

    def _segment(self, tab, h, M1, S, forcing: bool):
        """RK4 on the variational equation dS/dt = [[0, 1], [Jq, Jdq]] S (+ [0; F])
        over one segment; symbolic in M1 (SX)."""
        lin, basis = tab
        K = lin.D11.size // 3
        Jq, Jdq, den = lin.coefficients(M1)
        if forcing:
            # v_c = a(t) y_i + b(t) dy_i per component: forcing columns 2..5 (y_i), 6..9 (dy_i)
            a, b = basis
            Fy, Fdy = lin.forcing(*a), lin.forcing(*b)             # nu x 3K (numbers)

        def rhs(S, i):
            d1 = Jq[i] * S[0, :] + Jdq[i] * S[1, :]
            if forcing:
                d1 = d1 + ca.horzcat(ca.DM.zeros(1, 2), ca.DM(Fy[:, i]).T,
                                     ca.DM(Fdy[:, i]).T) / den[i]
            return ca.vertcat(S[1, :], d1)

        stage = {0.0: 0, 0.5: 1, 1.0: 2}          # table column of each RK4 stage
        for k in range(K):
            S = rk4_step(lambda Sv, c: rhs(Sv, 3 * k + stage[c]), S, h)
        return S

    def _build(self):
        M1 = ca.SX.sym("M1", self.model.nu)
        P = self._segment(self.pre, self.h_pre, M1, ca.SX.eye(2), forcing=False)
        MT = ca.vertcat(1, -M1)
        dtau = -ca.dot(MT, ca.DM(self.grad_z)) * P[0, :] / self.zdot            # 1 x 2
        dq_m = ca.mtimes(MT, P[0, :]) + ca.mtimes(ca.DM(self.dqT), dtau)       # nq x 2
        ddq_m = ca.mtimes(MT, P[1, :]) + ca.mtimes(ca.DM(self.ddqT), dtau)
        plus = ca.mtimes(ca.DM(self.J_impact), ca.vertcat(dq_m, ddq_m))       # 2 nq x 2
        nq = self.model.nq
        dqp, ddqp = plus[:nq, :], plus[nq:, :]
        dy = outputs(M1, dqp)                     # eq. (5), both columns
        ddy = outputs(M1, ddqp)
        W = ca.vertcat(dqp[0, :], ddqp[0, :], dy, ddy)                         # 2 nq x 2
        S0 = ca.horzcat(ca.SX.eye(2), ca.SX.zeros(2, 2 * self.model.nu))
        S = self._segment(self.post, self.h_post, M1, S0, forcing=True)
        A = ca.mtimes(S, W)
        tr = A[0, 0] + A[1, 1]
        det = A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]
        self._fns = (ca.Function("A_z", [M1], [A], ["M1"], ["A"]),
                     ca.Function("trace_det", [M1], [tr, det], ["M1"], ["trace", "det"]))

    @property
    def cache_key(self):
        """What the tables depend on."""
        return (self.gait.cache_key, self.n_pre, self.n_post, self.t_c)

    def jacobian(self, M1) -> np.ndarray:
        """A^z for one non-singular M1.

        As :meth:`jacobians`: on the compiled kernels where they build, else
        :attr:`A_fn`.

        Parameters
        ----------
        M1 : array_like
            (nu,).

        Returns
        -------
        numpy.ndarray
            (2, 2).
        """
        return self.jacobians(np.asarray(M1, dtype=float).reshape(1, -1), threads=1)[0]

    @staticmethod
    def _node_table(tab, forcing: bool) -> np.ndarray:
        """Per RK4 step, the coefficient factors at its three stage times (and the
        forcing's numerators after the impact): the node input of :func:`_step_kernels`."""
        lin, basis = tab
        K = lin.D11.size // 3
        parts = [lin.D11[None, :], lin.D12, lin.w0[None, :], lin.wa, lin.h0[None, :], lin.ha]
        if forcing:
            a, b = basis
            parts += [lin.forcing(*a), lin.forcing(*b)]
        rows = np.concatenate(parts)                                   # (m, 3K)
        return rows.reshape(len(rows), K, 3).transpose(2, 0, 1).reshape(-1, K)

    def _jacobians_kernel(self, M1s, kern, threads: int) -> np.ndarray:
        """A^z for many M1: both segments on the compiled kernels, the impact in numpy."""
        n, nq = len(M1s), self.model.nq
        if not hasattr(self, "_tables"):
            self._tables = (self._node_table(self.pre, False), self._node_table(self.post, True))
        pre, post = self._tables
        S = np.broadcast_to(np.eye(2).reshape(-1, 1, order="F"), (4, n))
        P = kern["pre"](S, M1s.T, pre, [self.h_pre], K=pre.shape[1], threads=threads)[0]
        P = P[:, :, 0].T.reshape(n, 2, 2, order="F")                       # (n, 2, 2)
        MT = np.concatenate([np.ones((n, 1)), -M1s], axis=1)                  # (n, nq)
        dtau = -(MT @ self.grad_z)[:, None] * P[:, 0, :] / self.zdot          # (n, 2)
        dq_m = MT[:, :, None] * P[:, 0, None, :] + self.dqT[None, :, None] * dtau[:, None, :]
        ddq_m = MT[:, :, None] * P[:, 1, None, :] + self.ddqT[None, :, None] * dtau[:, None, :]
        plus = self.J_impact[None] @ np.concatenate([dq_m, ddq_m], axis=1)   # (n, 2 nq, 2)
        dqp, ddqp = plus[:, :nq], plus[:, nq:]
        dy = M1s[:, :, None] * dqp[:, :1] + dqp[:, 1:]                        # eq. (5)
        ddy = M1s[:, :, None] * ddqp[:, :1] + ddqp[:, 1:]
        W = np.concatenate([dqp[:, :1], ddqp[:, :1], dy, ddy], axis=1)        # (n, 2 nq, 2)
        S0 = np.zeros((2, 2 * nq))
        S0[0, 0] = S0[1, 1] = 1.0
        S0 = np.broadcast_to(S0.reshape(-1, 1, order="F"), (4 * nq, n))
        S = kern["post"](S0, M1s.T, post, [self.h_post], K=post.shape[1], threads=threads)[0]
        S = S[:, :, 0].T.reshape(n, 2, 2 * nq, order="F")
        return S @ W

    @cached(maxsize=8)
    def _mapped(self, n: int, threads: int) -> ca.Function:
        return self.A_fn.map(n, "thread", threads)

    def jacobians(self, M1s: np.ndarray, threads: int = 2) -> np.ndarray:
        """A^z for many non-singular M1, on threads.

        The RK4 steps of both segments run on compiled four-lane kernels
        (:func:`_step_kernels`: the same stages and tables as :attr:`A_fn`, equal to it
        to round-off), the impact's algebra in numpy; where the kernels cannot be built,
        :attr:`A_fn` mapped over the points.

        Parameters
        ----------
        M1s : numpy.ndarray
            (n, nu).
        threads : int
            Threads.

        Returns
        -------
        numpy.ndarray
            (n, 2, 2).
        """
        M1s = np.atleast_2d(np.asarray(M1s, dtype=float))
        n = len(M1s)
        if n == 0:
            return np.zeros((0, 2, 2))
        kern = _step_kernels(self.model.nu)
        if kern is not None:
            return self._jacobians_kernel(M1s, kern, threads)
        A = np.array(self._mapped(n, threads)(M1s.T))            # 2 x 2n
        return A.reshape(2, n, 2).transpose(1, 0, 2)


@cached(maxsize=4)
def _step_kernels(nu: int):
    """One RK4 step of the variational equation as four-lane kernels (M1 per lane, the
    coefficient factors per step): 'pre' (S 2 x 2) and 'post' (S 2 x (2 + 2 nu), with the
    correction's forcing); None where :mod:`biped_casadi.simd` cannot build them.  They
    depend on nu only: one library per number of torques, kept in the cache."""
    from biped_casadi import simd
    M1, h = ca.SX.sym("M1", nu), ca.SX.sym("h")
    specs = {}
    for key, c, forcing in (("pre", 2, False), ("post", 2 + 2 * nu, True)):
        m = 3 + 3 * nu + (2 * nu if forcing else 0)           # factors per stage
        S = ca.SX.sym("S", 2, c)
        tab = ca.SX.sym("tab", 3 * m)
        coef = []
        for j in range(3):
            r = tab[j * m:(j + 1) * m]
            D11, D12 = r[0], r[1:1 + nu]
            w0, wa = r[1 + nu], r[2 + nu:2 + 2 * nu]
            h0, ha = r[2 + 2 * nu], r[3 + 2 * nu:3 + 3 * nu]
            den = D11 - ca.dot(D12, M1)                       # eq. (24)
            F = ca.vertcat(0, 0, r[3 + 3 * nu:]).T / den if forcing else 0
            coef.append(((w0 - ca.dot(wa, M1)) / den, (-h0 + ca.dot(ha, M1)) / den, F))

        def rhs(Sv, cc, coef=coef):
            Jq, Jdq, F = coef[{0.0: 0, 0.5: 1, 1.0: 2}[cc]]
            return ca.vertcat(Sv[1, :], Jq * Sv[0, :] + Jdq * Sv[1, :] + F)

        Sn = rk4_step(rhs, S, h)
        f = ca.Function(f"variational_{key}_nu{nu}", [ca.vec(S), M1, tab, h], [ca.vec(Sn)])
        specs[key] = (f, 1, ("sample", "node", "const"), True)
    return simd.kernels(specs, f"variational_nu{nu}", "-O2")


@cached(maxsize=8)
def variational_jacobian(gait, tau_s: float, n_pre: int, n_post: int,
                         rejoin: float = 0.5) -> VariationalJacobian:
    """The :class:`VariationalJacobian` of a gait and discretisation (memoised).

    Parameters
    ----------
    gait : Reference
        The reference step.
    tau_s : float
        Section time, s.
    n_pre, n_post : int
        RK4 steps before and after the impact.
    rejoin : float
        Rejoin time of v_c, fraction of T.

    Returns
    -------
    VariationalJacobian
    """
    return VariationalJacobian(require_reference(gait).model, gait, tau_s, n_pre, n_post, rejoin)
