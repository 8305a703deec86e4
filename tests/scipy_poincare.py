"""A plain SciPy implementation of the restricted Poincaré map (paper §IV, SPEC §4):
``solve_ivp`` with event location for the impact, central finite differences for A^z.

It shares only the model's D, H, impact map and the gait's q^d(t) with the toolkit
(the zero dynamics, the reference continuation, the event handling, v_c and the
Jacobian are written out again here), so it serves as an independent check of
analysis.stability (the finite-difference twin of its AD Jacobian) and as the speed
baseline of benchmarks/bench_sweep.py.
"""
from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp


def v_correction(tau, yi, dyi, T):
    """v_c of eq. (18), written independently: the quartic c0 + c1 s + ... + c4 s^4 on
    [0, T/2] with v_c(0) = y_i, v_c'(0) = dy_i and v_c, v_c', v_c'' = 0 at T/2 (solved as
    a linear system), zero afterwards; returns (v_c, dv_c, ddv_c)."""
    h = T / 2
    if tau >= h:
        z = np.zeros_like(np.asarray(yi, float))
        return z, z, z
    A = np.array([[1, 0, 0, 0, 0], [0, 1, 0, 0, 0], [1, h, h**2, h**3, h**4],
                  [0, 1, 2 * h, 3 * h**2, 4 * h**3], [0, 0, 2, 6 * h, 12 * h**2]])
    rhs = np.vstack([np.asarray(yi, float), np.asarray(dyi, float), np.zeros((3, np.size(yi)))])
    c = np.linalg.solve(A, rhs)
    p = np.array([1, tau, tau**2, tau**3, tau**4])
    dp = np.array([0, 1, 2 * tau, 3 * tau**2, 4 * tau**3])
    ddp = np.array([0, 0, 2, 6 * tau, 12 * tau**2])
    return p @ c, dp @ c, ddp @ c


class ScipyPoincare:
    def __init__(self, model, gait, rtol=1e-12, atol=1e-12, method="DOP853"):
        self.m, self.g = model, gait
        self.T = gait.T
        self.tau_s = 0.75 * gait.T
        self.opts = dict(rtol=rtol, atol=atol, method=method)
        self.x_star = gait.state_at(self.tau_s)
        self.ref0 = (gait.q(0.0), gait.dq(0.0))

    def _rhs(self, tau, z, M1, yi, dyi):
        # z = (q_u, dq_u); the reference comes from the gait's tabulated q^d(t)
        qd, dqd, ddqd = (a[:, 0] for a in self.g.evaluate(np.array([tau])))
        vc, dvc, ddvc = v_correction(tau, yi, dyi, self.T)
        qa = qd[1:] + M1 * (qd[0] - z[0]) + vc
        dqa = dqd[1:] + M1 * (dqd[0] - z[1]) + dvc
        ddv = M1 * ddqd[0] + ddqd[1:] + ddvc
        q = np.r_[z[0], qa]
        dq = np.r_[z[1], dqa]
        D = np.array(self.m.D(q))
        H1 = float(self.m.H(q, dq)[0])
        ddqu = (-D[0, 1:] @ ddv - H1) / (D[0, 0] - D[0, 1:] @ M1)
        return np.array([z[1], ddqu])

    def _q(self, tau, z, M1):
        qd, dqd, _ = (a[:, 0] for a in self.g.evaluate(np.array([tau])))
        return (np.r_[z[0], qd[1:] + M1 * (qd[0] - z[0])],
                np.r_[z[1], dqd[1:] + M1 * (dqd[0] - z[1])])

    def __call__(self, x, M1):
        M1 = np.asarray(M1, float)
        zero = np.zeros(M1.size)

        def guard(tau, z, *args):
            q, _ = self._q(tau, z, M1)
            x_sw, z_sw = (float(v) for v in self.m.swing_foot(q))
            return z_sw if x_sw > 0 else 1.0
        guard.terminal = True
        guard.direction = -1
        sol = solve_ivp(self._rhs, (self.tau_s, 1.9 * self.T), np.asarray(x, float),
                        events=guard, args=(M1, zero, zero), **self.opts)
        if not sol.t_events[0].size:
            raise RuntimeError("no impact")
        ti = sol.t_events[0][0]
        zm = sol.y_events[0][0]
        qm, dqm = self._q(ti, zm, M1)
        qp, dqp = (np.array(v).ravel() for v in self.m.impact(qm, dqm))
        q0, dq0 = self.ref0
        yi = (M1 * qp[0] + qp[1:]) - (M1 * q0[0] + q0[1:])
        dyi = (M1 * dqp[0] + dqp[1:]) - (M1 * dq0[0] + dq0[1:])
        sol2 = solve_ivp(self._rhs, (0.0, self.tau_s), np.array([qp[0], dqp[0]]),
                         args=(M1, yi, dyi), **self.opts)
        return sol2.y[:, -1], ti

    def jacobian(self, M1, x=None, h=1e-5):
        x = self.x_star if x is None else np.asarray(x, float)
        A = np.zeros((2, 2))
        for j in range(2):
            e = np.zeros(2)
            e[j] = h * max(1.0, abs(x[j]))
            A[:, j] = (self(x + e, M1)[0] - self(x - e, M1)[0]) / (2 * e[j])
        return A
