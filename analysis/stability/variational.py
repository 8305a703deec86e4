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
from biped_casadi.numerics import rk4_step
from biped_casadi.control.output_law import outputs
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
        self.model, self.gait = model, gait
        self.T = T = gait.T
        self.t_c = rejoin * T
        self.n_pre, self.n_post = n_pre, n_post
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
        self._build()

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
        self.A_fn = ca.Function("A_z", [M1], [A], ["M1"], ["A"])
        tr = A[0, 0] + A[1, 1]
        det = A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]
        self.trace_det = ca.Function("trace_det", [M1], [tr, det], ["M1"], ["trace", "det"])

    @property
    def cache_key(self):
        """What the tables depend on."""
        return (self.gait.cache_key, self.n_pre, self.n_post, self.t_c)

    def jacobian(self, M1) -> np.ndarray:
        """A^z for one non-singular M1.

        Parameters
        ----------
        M1 : array_like
            (nu,).

        Returns
        -------
        numpy.ndarray
            (2, 2).
        """
        return np.array(self.A_fn(np.asarray(M1, dtype=float)))

    @cached(maxsize=8)
    def _mapped(self, n: int, threads: int) -> ca.Function:
        return self.A_fn.map(n, "thread", threads)

    def jacobians(self, M1s: np.ndarray, threads: int = 2) -> np.ndarray:
        """A^z for many non-singular M1, on threads.

        Parameters
        ----------
        M1s : numpy.ndarray
            (n, nu).
        threads : int
            Threads of the mapped Function.

        Returns
        -------
        numpy.ndarray
            (n, 2, 2).
        """
        M1s = np.asarray(M1s, dtype=float)
        n = len(M1s)
        A = np.array(self._mapped(n, threads)(M1s.T))            # 2 x 2n
        return A.reshape(2, n, 2).transpose(1, 0, 2)


@cached(maxsize=8)
def variational_jacobian(model, gait, tau_s: float, n_pre: int, n_post: int,
                         rejoin: float = 0.5) -> VariationalJacobian:
    """The :class:`VariationalJacobian` of a gait and discretisation (memoised).

    Parameters
    ----------
    model : BipedModel
        The robot.
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
    return VariationalJacobian(model, gait, tau_s, n_pre, n_post, rejoin)
