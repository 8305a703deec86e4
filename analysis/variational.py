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
:class:`analysis.poincare.PoincareMap`, whose full AD Jacobian this reproduces to
integration accuracy (tests/test_poincare.py).
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from biped_casadi.correction import v_correction

__all__ = ["VariationalJacobian"]


def _rk4_times(t0, t1, n):
    h = (t1 - t0) / n
    t = t0 + h * np.arange(n)
    return h, np.stack([t, t + h / 2, t + h], axis=1)       # (n, 3): t, mid, end


class VariationalJacobian:
    """Precomputes the M1-independent coefficient tables once per gait."""

    def __init__(self, model, gait, tau_s: float, n_pre: int, n_post: int):
        self.model, self.gait = model, gait
        self.T = T = gait.T
        self.n_pre, self.n_post = n_pre, n_post
        q, dq = model.q_sym, model.dq_sym
        D, H = model.D_expr, model.H_expr
        coeffs = ca.Function("zd_coefficients", [q, dq], [
            D[0, 0], D[0, 1:].T, ca.jacobian(D[0, 0], q).T, ca.jacobian(D[0, 1:].T, q),
            ca.jacobian(H[0], q).T, ca.jacobian(H[0], dq).T])
        self._coeffs = coeffs
        self.h_pre, self.t_pre = _rk4_times(tau_s, T, n_pre)
        self.h_post, self.t_post = _rk4_times(0.0, tau_s, n_post)
        self.pre = self._table(self.t_pre)
        self.post = self._table(self.t_post, with_vc=True)

        # impact: gradient of the guard, strike speed, linearised impact map at T
        qT, dqT, ddqT = gait._eval(np.array([T]))
        qT, dqT, ddqT = qT[:, 0], dqT[:, 0], ddqT[:, 0]
        zsw = model.swing_foot(q)[1]
        self.grad_z = np.array(ca.Function("gz", [q], [ca.gradient(zsw, q)])(qT)).ravel()
        self.zdot = float(self.grad_z @ dqT)
        qp, dqp = model.impact(q, dq)
        JD = ca.Function("JD", [q, dq], [ca.jacobian(ca.vertcat(qp, dqp), ca.vertcat(q, dq))])
        self.J_impact = np.array(JD(qT, dqT))                 # 10 x 10
        self.dqT, self.ddqT = dqT, ddqT

    def _table(self, times, with_vc=False):
        g = self.gait
        t = times.ravel()
        q, dq, ddq = g._eval(t)
        n = t.size
        D11, D12, gD11, GD12, gH1q, gH1dq = (np.array(v) for v in self._coeffs.map(n)(q, dq))
        D11 = D11.ravel()
        GD12 = GD12.reshape(4, 5, n, order="F")               # dD12_i/dq_j
        ddr, ddqa = ddq[0], ddq[1:]
        w = -np.einsum("in,ijn->jn", ddqa, GD12) - gH1q - ddr * gD11      # 5 x n
        tab = dict(D11=D11, D12=D12, w0=w[0], wa=w[1:], h0=gH1dq[0], ha=gH1dq[1:])
        if with_vc:
            T = self.T
            a = v_correction(t, 1.0, 0.0, T)      # v_c = a y_i + b dy_i (per component)
            b = v_correction(t, 0.0, 1.0, T)
            tab.update(a=np.stack(a), b=np.stack(b))
        shape = times.shape
        return {k: v.reshape(v.shape[:-1] + shape) for k, v in tab.items()}

    @staticmethod
    def _coefficients(tab, M1):
        """Jq, Jdq (n, K, 3) and, with v_c, the forcing Fy, Fdy (n, K, 3, 4)."""
        den = tab["D11"][None] - np.einsum("nj,jks->nks", M1, tab["D12"])
        Jq = (tab["w0"][None] - np.einsum("nj,jks->nks", M1, tab["wa"])) / den
        Jdq = (-tab["h0"][None] + np.einsum("nj,jks->nks", M1, tab["ha"])) / den
        if "a" not in tab:
            return Jq, Jdq, None, None
        wa, ha, D12 = tab["wa"], tab["ha"], tab["D12"]
        a, b = tab["a"], tab["b"]
        Fy = (wa * a[0] - ha * a[1] - D12 * a[2]) / den[:, None]
        Fdy = (wa * b[0] - ha * b[1] - D12 * b[2]) / den[:, None]
        return Jq, Jdq, np.moveaxis(Fy, 1, -1), np.moveaxis(Fdy, 1, -1)

    @staticmethod
    def _rk4(S, h, Jq, Jdq, F=None):
        """Integrate dS/dt = [[0, 1], [Jq, Jdq]] S (+ [0; F]) over the grid; S (n, 2, c)."""
        def rhs(S, k, st):
            d0 = S[:, 1]
            d1 = Jq[:, k, st, None] * S[:, 0] + Jdq[:, k, st, None] * S[:, 1]
            if F is not None:
                d1 = d1 + F[:, k, st]
            return np.stack([d0, d1], axis=1)
        for k in range(Jq.shape[1]):
            k1 = rhs(S, k, 0)
            k2 = rhs(S + h / 2 * k1, k, 1)
            k3 = rhs(S + h / 2 * k2, k, 1)
            k4 = rhs(S + h * k3, k, 2)
            S = S + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        return S

    def jacobians(self, M1s: np.ndarray) -> np.ndarray:
        """A^z (n, 2, 2) for an (n, 4) array of non-singular M1."""
        M1s = np.asarray(M1s, dtype=float)
        n = len(M1s)
        Jq, Jdq, _, _ = self._coefficients(self.pre, M1s)
        P = self._rk4(np.repeat(np.eye(2)[None], n, 0), self.h_pre, Jq, Jdq)   # (n,2,2)
        MT = np.concatenate([np.ones((n, 1)), -M1s], axis=1)                  # (n,5)
        dtau = -(MT @ self.grad_z)[:, None] * P[:, 0] / self.zdot             # (n,2)
        dq_m = MT[:, :, None] * P[:, None, 0] + self.dqT[None, :, None] * dtau[:, None]
        ddq_m = MT[:, :, None] * P[:, None, 1] + self.ddqT[None, :, None] * dtau[:, None]
        plus = np.einsum("ij,njc->nic", self.J_impact, np.concatenate([dq_m, ddq_m], axis=1))
        dqp, ddqp = plus[:, :5], plus[:, 5:]
        dy = dqp[:, 1:] + M1s[:, :, None] * dqp[:, None, 0]
        ddy = ddqp[:, 1:] + M1s[:, :, None] * ddqp[:, None, 0]
        W = np.concatenate([dqp[:, :1], ddqp[:, :1], dy, ddy], axis=1)         # (n,10,2)
        Jq, Jdq, Fy, Fdy = self._coefficients(self.post, M1s)
        # sensitivity of the post-impact state to (z+, y_i, dy_i): S (n, 2, 10)
        S = np.zeros((n, 2, 10))
        S[:, 0, 0] = S[:, 1, 1] = 1.0
        F = np.zeros(Fy.shape[:3] + (10,))
        F[..., 2:6] = Fy
        F[..., 6:10] = Fdy
        S = self._rk4(S, self.h_post, Jq, Jdq, F)
        return S @ W
