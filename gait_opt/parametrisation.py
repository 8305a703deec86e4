"""The gait parametrisation shared by the optimiser and the Gait object.

q_a^d(t): a Bezier polynomial of degree M in s = t / T (nu x (M+1) coefficients alpha,
nu = the model's number of torques: 4 for RABBIT).
Being a polynomial, it and all its time derivatives exist everywhere and continue
smoothly past T (docs: theory §3: the reference after T is the same polynomial
evaluated for s > 1).

q_u^d(t): the solution of the unactuated row of eq. (1),
    D11(q) ddq_u + D12(q) ddq_a^d + H1(q, dq) = 0,  q = (q_u, q_a^d(t)),
from (q_u(0), dq_u(0)); it is integrated with fixed-step RK4 (error ~1e-12 at the
default 2000 steps per step) and evaluated between grid points by quintic Hermite
interpolation of (q_u, dq_u, ddq_u); ddq_u at any t is the unactuated row evaluated at
the interpolated state.  Past T the same ODE continues it, so the whole
reference is C^2 (indeed smooth) across T.
"""
from __future__ import annotations

import math
from math import comb

import casadi as ca
import numpy as np

from biped_casadi.caching import cached
from biped_casadi.numerics import quintic_hermite_interval, rk4_step
from biped_casadi.control.output_law import unactuated_acceleration

__all__ = ["ReferenceDynamics", "reference_dynamics", "bernstein", "quintic_hermite"]


def bernstein(M: int, s):
    """Bernstein basis b_{k,M}(s), k = 0..M (list; s numeric or CasADi)."""
    return [comb(M, k) * s**k * (1 - s)**(M - k) for k in range(M + 1)]


class ReferenceDynamics:
    """CasADi Functions of the gait parametrisation for one model and Bezier degree.

    ``qa(alpha, s, T)`` -> (qa, dqa, ddqa) with time derivatives;
    ``ddqu(q, dq, ddqa)`` the unactuated row of eq. (1) solved for ddq_u;
    ``torque(q, dq, ddq)`` rows 2..5 of D ddq + H (the model's inverse dynamics);
    ``full(x, alpha, s, T)`` -> (q, dq, ddq) with x = (q_u, dq_u);
    ``rk4(x, s, ds, alpha, T)`` one RK4 step of the unactuated row in s = t / T;
    ``integrate(n)`` -> Function(x0, s0, ds, alpha, T) -> 2 x n states after each step.
    """

    def __init__(self, model, degree: int, continuation: float | None = None,
                 shape: str = "ramp"):
        if degree < 3:
            raise ValueError(f"bezier_degree must be >= 3, got {degree}")
        self.model = model
        self.degree = M = degree
        self.continuation, self.shape = continuation, shape
        nu = model.nu
        alpha = ca.SX.sym("alpha", nu, M + 1)
        s = ca.SX.sym("s")
        T = ca.SX.sym("T")
        b = bernstein(M, s)
        b1 = bernstein(M - 1, s)
        b2 = bernstein(M - 2, s)
        qa = sum(alpha[:, k] * b[k] for k in range(M + 1))
        dqa = M * sum((alpha[:, k + 1] - alpha[:, k]) * b1[k] for k in range(M)) / T
        ddqa = M * (M - 1) * sum((alpha[:, k + 2] - 2 * alpha[:, k + 1] + alpha[:, k]) * b2[k]
                                 for k in range(M - 1)) / T**2
        if continuation is not None:
            qa, dqa, ddqa = _continued(qa, dqa, ddqa, s, T, continuation, shape)
        self.qa = ca.Function("qa", [alpha, s, T], [qa, dqa, ddqa],
                              ["alpha", "s", "T"], ["qa", "dqa", "ddqa"])

        q, dq = model.q_sym, model.dq_sym
        D, H = model.D_expr, model.H_expr
        dd_a = ca.SX.sym("ddqa", nu)
        # the unactuated row of eq. (1) with q_a prescribed: eq. (23) with M1 = 0
        ddqu = ca.cse(unactuated_acceleration(D, H, ca.DM.zeros(nu), dd_a))
        self.ddqu = ca.Function("ddqu", [q, dq, dd_a], [ddqu], ["q", "dq", "ddqa"], ["ddqu"])
        self.torque = model.inverse_dynamics          # rows 2..n of eq. (1)

        x = ca.SX.sym("x", 2)
        qa_, dqa_, ddqa_ = self.qa(alpha, s, T)
        qf = ca.vertcat(x[0], qa_)
        dqf = ca.vertcat(x[1], dqa_)
        a_u = self.ddqu(qf, dqf, ddqa_)
        self.full = ca.Function("full", [x, alpha, s, T], [qf, dqf, ca.vertcat(a_u, ddqa_)],
                                ["x", "alpha", "s", "T"], ["q", "dq", "ddq"])
        # unactuated row as a first-order ODE in s: dx/ds = T * (dq_u, ddq_u)
        f = ca.Function("f_s", [x, s, alpha, T], [T * ca.vertcat(x[1], a_u)])
        ds = ca.SX.sym("ds")
        xn = ca.cse(rk4_step(lambda xv, c: f(xv, s + c * ds, alpha, T), x, ds))
        self.rk4 = ca.Function("rk4", [x, s, ds, alpha, T], [xn, s + ds],
                               ["x", "s", "ds", "alpha", "T"], ["x_next", "s_next"])

    @property
    def cache_key(self):
        """What the Functions depend on: the model, the Bezier degree, the continuation."""
        return (self.model.cache_key, self.degree, self.continuation, self.shape)

    @cached(maxsize=8)
    def integrate(self, n: int) -> ca.Function:
        """Function(x0, s0, ds, alpha, T) -> X (2 x n): RK4 states after each of n steps."""
        x0 = ca.MX.sym("x0", 2)
        s0 = ca.MX.sym("s0")
        ds = ca.MX.sym("ds")
        alpha = ca.MX.sym("alpha", self.model.nu, self.degree + 1)
        T = ca.MX.sym("T")
        step = ca.Function("step", [x0, s0, ds, alpha, T], [*self.rk4(x0, s0, ds, alpha, T)])
        acc = step.mapaccum("rk4_acc", n, [0, 1], [0, 1])
        X, _ = acc(x0, s0, ds, alpha, T)
        return ca.Function(f"unactuated_rk4_{n}", [x0, s0, ds, alpha, T], [X],
                           ["x0", "s0", "ds", "alpha", "T"], ["X"])


def _continued(qa, dqa, ddqa, s, T, continuation, shape="ramp"):
    """q_a^d past T (s > 1) without the Bezier polynomials' growth.

    'ramp': the acceleration at T ramps linearly to zero over c T (c = ``continuation``;
    inf: kept constant), then the velocity stays constant; C^2 at T, like the polynomial
    itself.  'smooth': the acceleration decays as (a_T + k sigma) exp(-sigma / tau),
    tau = c T, sigma = t - T, with k = j_T + a_T / tau so that the jerk is continuous
    too (C^3 at T, smooth after)."""
    q1, v1, a1 = (ca.substitute(e, s, ca.SX(1)) for e in (qa, dqa, ddqa))
    sig = (s - 1) * T
    if shape == "smooth":
        tau = continuation * T
        j1 = ca.substitute(ca.jacobian(ddqa, s), s, ca.SX(1)) / T
        k = j1 + a1 / tau
        e = ca.exp(-sig / tau)
        ddqe = (a1 + k * sig) * e
        dqe = v1 + a1 * tau * (1 - e) + k * (tau**2 - (tau**2 + tau * sig) * e)
        qe = (q1 + v1 * sig + a1 * tau * sig - a1 * tau**2 * (1 - e)
              + k * (tau**2 * sig - 2 * tau**3 + (2 * tau**3 + tau**2 * sig) * e))
    elif math.isinf(continuation):
        qe, dqe, ddqe = q1 + v1 * sig + a1 * sig**2 / 2, v1 + a1 * sig, a1
    else:
        d = continuation * T
        r = ca.fmin(sig, d)
        qe = q1 + v1 * sig + a1 * (r**2 / 2 - r**3 / (6 * d)) + a1 * d / 2 * (sig - r)
        dqe = v1 + a1 * (r - r**2 / (2 * d))
        ddqe = a1 * (1 - r / d)
    # the switch sits just past s = 1: an impact time that lands on T to round-off
    # (the fixed point of the Poincare map) sees the polynomial on both sides, so the AD
    # derivative of the discrete map is the one-sided one of the continuous map (the
    # branches differ in jerk; within 1e-9 T they differ by ~jerk * (1e-9 T)^3)
    past = s > 1 + 1e-9
    return tuple(ca.if_else(past, e, b) for e, b in ((qe, qa), (dqe, dqa), (ddqe, ddqa)))


@cached(maxsize=16)
def reference_dynamics(model, degree: int, continuation: float | None = None,
                       shape: str = "ramp") -> ReferenceDynamics:
    """The :class:`ReferenceDynamics` of a model, Bezier degree and continuation past T
    (see :class:`gait_opt.GaitOptions`), memoised."""
    return ReferenceDynamics(model, degree, continuation, shape)


# quintic Hermite interpolation on a uniform grid --------------------------------
def quintic_hermite(t_grid, y, dy, ddy, t):
    """Value and first two derivatives at ``t`` of the quintic Hermite interpolant of
    (y, dy, ddy) given on the uniform grid ``t_grid``
    (:func:`biped_casadi.numerics.quintic_hermite_interval` on the interval around each
    t).  Vectorised over ``t``."""
    t = np.asarray(t, dtype=float)
    h = t_grid[1] - t_grid[0]
    i = np.clip(((t - t_grid[0]) // h).astype(int), 0, len(t_grid) - 2)
    th = (t - t_grid[i]) / h
    return quintic_hermite_interval(th, h, y[i], dy[i], ddy[i], y[i + 1], dy[i + 1],
                                    ddy[i + 1])
