"""The hybrid zero dynamics of the time-varying controller, composed once from the output law.

From the start of every step the correction v_c (eq. 17-18) makes y_c(0) = dy_c(0) = 0,
and the feedback-linearising law (12)-(13) keeps y_c = 0: the closed loop IS its hybrid
zero dynamics, for every output gain.  On it the outputs follow v = v^d(tau) + v_c(tau),
so the configuration is q = (q_u, v - M1 q_u) (eq. 10), the unactuated coordinate obeys
the first row of eq. (1) written in the outputs (eq. 19 with ddv = ddv^d + ddv_c, solved
by eq. 23), and the torques are the other rows (eq. 12).

Everything that integrates or analyses this closed loop composes it here: the restricted
Poincaré map (:mod:`analysis.stability.poincare`) and its variational equation
(:mod:`analysis.stability.variational`), the batched walker
(:mod:`biped_casadi.simulation.tv_walker`) and the robust co-design.  The reference enters
only through its values R = (q^d, dq^d, ddq^d) at tau, so it may be tabulated numbers (the
walker), a CasADi Function of tau and of a reference state integrated alongside
(:meth:`ZeroDynamics.along`, from :meth:`Reference.symbolic`), or symbolic in a gait's own
decision variables (the co-design NLP).

Layout of the step parameters P = (M1, t_c, y_i, dy_i): the outputs (nu), the time at which
v_c rejoins the reference (s), and the output error and rate just after the impact (nu
each), :meth:`ZeroDynamics.params`.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from ..caching import cached
from .output_law import (actuated_torque, coordinates_from_outputs, correction,
                         decoupling_denominator, initial_output_errors, outputs,
                         unactuated_acceleration)

__all__ = ["ZeroDynamics", "zero_dynamics", "Linearisation", "denominator_samples"]


@dataclass
class Linearisation:
    """The M1-independent factors of the zero dynamics linearised about a reference.

    About the reference the closed loop follows q^d exactly for every M1, so the
    linearisation of eq. (19) has coefficients rational in M1 with factors taken along
    q^d (by AD of D and H):

        (D11 - D12 M1) d(ddq_u) = w . dq - h . d(dq) - D12 d(ddv),
        w = -(dD12/dq)' ddq_a^d - dH1/dq - ddq_u^d dD11/dq,   h = dH1/d(dq),

    with dq = (1, -M1) d(q_u) + (0, dv_c) and d(dq) likewise: M1 cancels from w because
    ddv^d - M1 ddq_u^d = ddq_a^d.  Arrays along the last axis are the points given.

    Parameters
    ----------
    D11 : numpy.ndarray
        (N,) D11 along the reference.
    D12 : numpy.ndarray
        (nu, N) the rest of D's first row.
    w0, wa : numpy.ndarray
        (N,), (nu, N): w split into its unactuated and actuated components.
    h0, ha : numpy.ndarray
        (N,), (nu, N): h likewise.
    """

    D11: np.ndarray
    D12: np.ndarray
    w0: np.ndarray
    wa: np.ndarray
    h0: np.ndarray
    ha: np.ndarray

    def coefficients(self, M1):
        """The linearised zero dynamics d(ddq_u) = Jq d(q_u) + Jdq d(dq_u) + forcing / den.

        Parameters
        ----------
        M1 : casadi.SX or array_like
            (nu,) outputs (symbolic for an A^z that is a function of M1).

        Returns
        -------
        tuple
            (Jq, Jdq, den), each (N,): the coefficients of d(q_u) and d(dq_u), and the
            decoupling denominator D11 - D12 M1 (eq. 24) at the points.
        """
        den = decoupling_denominator(ca.DM(self.D11), ca.DM(self.D12).T, M1)
        Jq = (ca.DM(self.w0) - ca.mtimes(ca.DM(self.wa).T, M1)) / den
        Jdq = (-ca.DM(self.h0) + ca.mtimes(ca.DM(self.ha).T, M1)) / den
        return Jq, Jdq, den

    def forcing(self, v, dv, ddv) -> np.ndarray:
        """The numerator w_a . v - h_a . dv - D12 . ddv of an output perturbation's forcing.

        Parameters
        ----------
        v, dv, ddv : numpy.ndarray
            (N,) a perturbation of the outputs, the same on every component (such as a
            column of :meth:`ZeroDynamics.correction_basis`), and its two derivatives.

        Returns
        -------
        numpy.ndarray
            (nu, N): per output component, the forcing of d(ddq_u) times the denominator.
        """
        return self.wa * v - self.ha * dv - self.D12 * ddv


class ZeroDynamics:
    """The hybrid zero dynamics of the time-varying controller of one robot, built once.

    Implements eq. (19): with the outputs v = v^d + v_c, q_a = v - M1 q_u (eq. 10) and
    ddq_u from the first row of eq. (1) (eq. 23), the state (q_u, dq_u) of the closed loop
    evolves autonomously given the reference and the step's correction parameters.

    Parameters
    ----------
    model : BipedModel
        The robot.

    Notes
    -----
    CasADi Functions, of x = (q_u, dq_u), tau, R = (q^d, dq^d, ddq^d) at tau (3 nq) and
    the step parameters P (:meth:`params`):

    - ``rhs(x, tau, R, P) -> dx``: the zero dynamics as a first-order ODE;
    - ``state(x, tau, R, P) -> (q, dq, ddq)``: the full state on the zero dynamics;
    - ``point(x, tau, R, P) -> (q, dq, ddq, u, Fx, Fz, den)``: with the torques of eq. (12),
      the stance reaction and the decoupling denominator D11 - D12 M1 of eq. (24);
    - ``step_start(q, dq, R0, M1) -> (x, y_i, dy_i)``: the zero-dynamics state and the
      correction's start (eq. 17) of a step starting at the full state (q, dq), R0 the
      reference at tau = 0.
    """

    def __init__(self, model):
        self.model = model
        self.nq, self.nu = nq, nu = model.nq, model.nu
        self.n_par = 3 * nu + 1
        x, tau = ca.SX.sym("x", 2), ca.SX.sym("tau")
        R, P = ca.SX.sym("R", 3 * nq), ca.SX.sym("P", self.n_par)
        q, dq, ddq, ddv, D, H, ddqu, M1 = self.compose(x, tau, R, P)
        u = actuated_torque(D, H, M1, ddqu, ddv)                                # eq. (12)
        Fx, Fz = model.ground_reaction_acc(q, dq, ddq)
        den = decoupling_denominator(D[0, 0], D[0, 1:], M1)                      # eq. (24)
        names = ["x", "tau", "R", "P"]
        self.rhs = ca.Function("zd_rhs", [x, tau, R, P], [ca.vertcat(x[1], ddqu)], names,
                               ["dx"])
        self.state = ca.Function("zd_state", [x, tau, R, P], [q, dq, ddq], names,
                                 ["q", "dq", "ddq"])
        self.point = ca.Function("zd_point", [x, tau, R, P], [q, dq, ddq, u, Fx, Fz, den],
                                 names, ["q", "dq", "ddq", "u", "Fx", "Fz", "den"])
        qs, dqs, R0, M1s = (ca.SX.sym("q", nq), ca.SX.sym("dq", nq), ca.SX.sym("R0", 3 * nq),
                            ca.SX.sym("M1", nu))
        yi, dyi = initial_output_errors(M1s, qs, dqs, R0[:nq], R0[nq:2 * nq])     # eq. (17)
        self.step_start = ca.Function("zd_step_start", [qs, dqs, R0, M1s],
                                      [ca.vertcat(qs[0], dqs[0]), yi, dyi],
                                      ["q", "dq", "R0", "M1"], ["x", "y_i", "dy_i"])

    @property
    def cache_key(self):
        """What the Functions depend on: the model."""
        return self.model.cache_key

    # ------------------------------------------------------------ composition
    def split(self, P):
        """(M1, t_c, y_i, dy_i) of step parameters P (numbers or CasADi).

        Parameters
        ----------
        P : array_like or casadi
            (3 nu + 1,) step parameters, or numpy (n, 3 nu + 1) for n scenarios.

        Returns
        -------
        tuple
            M1 (nu), t_c, y_i (nu), dy_i (nu), along the last axis for numpy input.
        """
        nu = self.nu
        if isinstance(P, np.ndarray):
            return P[..., :nu], P[..., nu], P[..., nu + 1:2 * nu + 1], P[..., 2 * nu + 1:]
        return P[:nu], P[nu], P[nu + 1:2 * nu + 1], P[2 * nu + 1:]

    def params(self, M1, t_c, y_i, dy_i):
        """The step parameters P = (M1, t_c, y_i, dy_i), CasADi or numpy.

        Parameters
        ----------
        M1 : array_like or casadi
            (nu,) outputs; numpy (n, nu) for n scenarios.
        t_c : float, array_like or casadi
            Rejoin time of v_c, s (eq. 18); (n,) for n scenarios.
        y_i, dy_i : array_like or casadi
            Output error and rate at the start of the step (nu each; (n, nu)).

        Returns
        -------
        numpy.ndarray or casadi
            (3 nu + 1,) or (n, 3 nu + 1).
        """
        if any(isinstance(a, (ca.SX, ca.MX)) for a in (M1, t_c, y_i, dy_i)):
            return ca.vertcat(M1, t_c, y_i, dy_i)
        M1, y_i, dy_i = (np.atleast_2d(np.asarray(a, float)) for a in (M1, y_i, dy_i))
        n = max(len(M1), len(y_i), len(dy_i), np.size(t_c))
        tc = np.broadcast_to(np.asarray(t_c, float), (n,))[:, None]
        out = np.hstack([np.broadcast_to(M1, (n, self.nu)), tc,
                         np.broadcast_to(y_i, (n, self.nu)), np.broadcast_to(dy_i, (n, self.nu))])
        return out[0] if out.shape[0] == 1 and np.ndim(M1) == 1 else out

    def compose(self, x, tau, R, P):
        """The zero dynamics at one point, as expressions (symbolic or numeric).

        Parameters
        ----------
        x : casadi
            (q_u, dq_u), rad and rad/s.
        tau : casadi or float
            Time since the start of the step, s.
        R : casadi
            (q^d, dq^d, ddq^d) at tau, 3 nq.
        P : casadi
            Step parameters (:meth:`params`).

        Returns
        -------
        tuple
            (q, dq, ddq, ddv, D, H, ddq_u, M1): configuration, velocity and acceleration
            on the zero dynamics, the output acceleration, D and H there, ddq_u (eq. 23)
            and the outputs.
        """
        nq = self.nq
        M1, tc, yi, dyi = self.split(P)
        qd, dqd, ddqd = R[:nq], R[nq:2 * nq], R[2 * nq:]
        vc, dvc, ddvc = correction(tau, yi, dyi, tc)                          # eq. (18)
        q = coordinates_from_outputs(M1, x[0], outputs(M1, qd) + vc)          # eq. (10)
        dq = coordinates_from_outputs(M1, x[1], outputs(M1, dqd) + dvc)
        ddv = outputs(M1, ddqd) + ddvc
        D, H = self.model.D(q), self.model.H(q, dq)
        ddqu = unactuated_acceleration(D, H, M1, ddv)                          # eq. (23)
        ddq = coordinates_from_outputs(M1, ddqu, ddv)
        return q, dq, ddq, ddv, D, H, ddqu, M1

    @cached(maxsize=16)
    def along(self, reference, parametric: bool = False) -> ca.Function:
        """The zero dynamics with a reference integrated alongside.

        The state is z = (q_u, dq_u, r), r the reference state of
        :meth:`Reference.symbolic` (for a gait (q_u^d, dq_u^d)), so that q^d stays exact
        in any fixed-step scheme and continues past T as the reference defines it.

        Parameters
        ----------
        reference : Reference
            The reference step.
        parametric : bool
            Take the reference's parameters as a last input ``theta``
            (:meth:`Reference.symbolic_parametric`): one Function for references of one
            kind.

        Returns
        -------
        casadi.Function
            ``(z, tau, P) -> (dz, q, dq)`` (``(z, tau, P, theta)`` when parametric): the
            time derivative of z, and the configuration and velocity on the zero
            dynamics.
        """
        nr = reference.n_state
        z, tau, P = ca.SX.sym("z", 2 + nr), ca.SX.sym("tau"), ca.SX.sym("P", self.n_par)
        if parametric:
            ref, theta = reference.symbolic_parametric()
            th = ca.SX.sym("theta", theta.size)
            qd, dqd, ddqd, dr = ref(tau, z[2:], th)
        else:
            qd, dqd, ddqd, dr = reference.symbolic()(tau, z[2:])
        R = ca.vertcat(qd, dqd, ddqd)
        q, dq, _ = self.state(z[:2], tau, R, P)
        return ca.Function("zd_along_reference", [z, tau, P] + ([th] if parametric else []),
                           [ca.vertcat(self.rhs(z[:2], tau, R, P), dr), q, dq],
                           ["z", "tau", "P"] + (["theta"] if parametric else []),
                           ["dz", "q", "dq"])

    # ---------------------------------------------------- linearisation (eq. 20)
    @cached(maxsize=2)
    def _factors(self) -> ca.Function:
        m = self.model
        q, dq = m.q_sym, m.dq_sym
        D, H = m.D_expr, m.H_expr
        return ca.Function("zd_linear_factors", [q, dq], [
            D[0, 0], D[0, 1:].T, ca.jacobian(D[0, 0], q).T, ca.jacobian(D[0, 1:].T, q),
            ca.jacobian(H[0], q).T, ca.jacobian(H[0], dq).T])

    def linearisation(self, qd, dqd, ddqd) -> Linearisation:
        """The factors of the zero dynamics linearised about reference points.

        Parameters
        ----------
        qd, dqd, ddqd : numpy.ndarray
            (nq, N) the reference and its derivatives at N points.

        Returns
        -------
        Linearisation
            The M1-independent tables (see its docstring).
        """
        nq, n = self.nq, qd.shape[1]
        D11, D12, gD11, GD12, gH1q, gH1dq = (np.array(v) for v in self._factors().map(n)(qd, dqd))
        GD12 = GD12.reshape(nq - 1, nq, n, order="F")              # dD12_i / dq_j
        w = -np.einsum("in,ijn->jn", ddqd[1:], GD12) - gH1q - ddqd[0] * gD11
        return Linearisation(D11=D11.ravel(), D12=D12, w0=w[0], wa=w[1:], h0=gH1dq[0],
                             ha=gH1dq[1:])

    @staticmethod
    def correction_basis(t, t_c):
        """v_c of eq. (18) per unit y_i and per unit dy_i, with their two derivatives.

        v_c is linear in the step's (y_i, dy_i): per component, v_c = a(t) y_i + b(t) dy_i.

        Parameters
        ----------
        t : numpy.ndarray
            (N,) times since the start of the step, s.
        t_c : float
            Rejoin time, s.

        Returns
        -------
        tuple of numpy.ndarray
            (a, b), each (3, N): the value and the first two time derivatives.
        """
        return (np.stack(correction(t, 1.0, 0.0, t_c)), np.stack(correction(t, 0.0, 1.0, t_c)))


@cached(maxsize=8)
def zero_dynamics(model) -> ZeroDynamics:
    """The :class:`ZeroDynamics` of a robot, built once (memoised by the model).

    Parameters
    ----------
    model : BipedModel
        The robot.

    Returns
    -------
    ZeroDynamics
    """
    return ZeroDynamics(model)


@cached(maxsize=16)
def denominator_samples(reference, n: int = 1001):
    """D11 and D12 along a reference step: the samples of the eq. (24) denominator.

    Parameters
    ----------
    reference : Reference
        The reference step, [0, T].
    n : int
        Points on [0, T].

    Returns
    -------
    tuple of numpy.ndarray
        (D11 (n,), D12 (nu, n)); D11 - D12 M1 is the denominator of eq. (23) for outputs
        M1 (``output_law.decoupling_denominator``).
    """
    model = reference.model
    t = np.linspace(0.0, reference.T, n)
    nq = model.nq
    D = np.array(model.D.map(n)(reference.q(t))).reshape(nq, nq, n, order="F")
    return D[0, 0], D[0, 1:]
