"""A gait made the way another tool would make it (OptimTraj's Hermite-Simpson
collocation, in CasADi Opti), in another coordinate convention: absolute link angles phi
and their rates at the knots and midpoints of N intervals.  For the import tests and the
how-to (docs/howto/bring-your-robot.md); nothing of gait_opt is used.

Problem: one step of RABBIT at ``speed``, minimising the integral of u'u (Simpson's
rule on the knots and midpoints), periodic through the impact and relabelling, the
swing foot on the ground at T and above it at the interior knots, |u| <= 150 N m, no
knee hyperextension.  The dynamics are the model's D and H written in phi = L q
(L lower triangular ones): D(q) ddq + H = B u with ddq = L^-1 ddphi.
"""
from __future__ import annotations

import casadi as ca
import numpy as np


def hermite_simpson_gait(model, guess, n_intervals: int = 12, speed: float = 0.6):
    """(t, phi, dphi) at the 2 N + 1 knots and midpoints: arrays (2N+1,), (nq, 2N+1) x 2.

    ``guess``: a gait of the toolkit used only as the initial guess (scaled to the
    speed)."""
    n, nu, N = model.nq, model.nu, n_intervals
    Lm = np.tril(np.ones((n, n)))               # phi = L q
    S = np.linalg.inv(Lm)                       # q = S phi
    opti = ca.Opti()
    X = opti.variable(2 * n, 2 * N + 1)         # (phi, dphi) at knots and midpoints
    U = opti.variable(nu, 2 * N + 1)
    T = opti.variable()
    h = T / N

    def f(x, u):
        q, dq = ca.mtimes(ca.DM(S), x[:n]), ca.mtimes(ca.DM(S), x[n:])
        ddq = ca.solve(model.D(q), ca.mtimes(ca.DM(model.B), u) - model.H(q, dq))
        return ca.vertcat(x[n:], ca.mtimes(ca.DM(Lm), ddq))

    F = [f(X[:, j], U[:, j]) for j in range(2 * N + 1)]
    for k in range(N):
        a, m, b = 2 * k, 2 * k + 1, 2 * k + 2
        opti.subject_to(X[:, m] == (X[:, a] + X[:, b]) / 2 + h / 8 * (F[a] - F[b]))
        opti.subject_to(X[:, b] - X[:, a] == h / 6 * (F[a] + 4 * F[m] + F[b]))
    q0, dq0 = ca.mtimes(ca.DM(S), X[:n, 0]), ca.mtimes(ca.DM(S), X[n:, 0])
    qT, dqT = ca.mtimes(ca.DM(S), X[:n, -1]), ca.mtimes(ca.DM(S), X[n:, -1])
    qp, dqp = model.impact(qT, dqT)
    opti.subject_to(qp == q0)
    opti.subject_to(dqp == dq0)
    xT, zT = model.swing_foot(qT)
    opti.subject_to(zT == 0)
    opti.subject_to(xT == speed * T)
    for j in range(1, 2 * N):
        q = ca.mtimes(ca.DM(S), X[:n, j])
        opti.subject_to(model.swing_foot(q)[1] >= 0.02 * 4 * (j / (2 * N)) * (1 - j / (2 * N)))
        opti.subject_to(q[1] <= 0)
        opti.subject_to(q[4] >= 0)
    opti.subject_to(opti.bounded(-150, ca.vec(U), 150))
    opti.subject_to(opti.bounded(0.2, T, 1.5))
    w = np.ones(2 * N + 1)
    w[1::2], w[2:-1:2] = 4, 2
    opti.minimize(h / 6 * sum(w[j] * ca.sumsqr(U[:, j]) for j in range(2 * N + 1)))
    T0 = guess.step_length / speed
    tg = np.linspace(0, guess.T, 2 * N + 1)
    qg, dqg, _ = guess.evaluate(tg)
    opti.set_initial(X, np.vstack([Lm @ qg, Lm @ dqg * guess.T / T0]))
    opti.set_initial(U, guess.u(tg) * 0 + np.array(guess.u(tg)))
    opti.set_initial(T, T0)
    opti.solver("ipopt", {"print_time": False}, {"print_level": 0, "tol": 1e-10,
                                                 "max_iter": 500})
    sol = opti.solve()
    Xv, Tv = np.array(sol.value(X)), float(sol.value(T))
    return np.linspace(0, Tv, 2 * N + 1), Xv[:n], Xv[n:]
