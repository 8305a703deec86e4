"""The walking simulator's stance force, friction cone and torques checked between its
RK4 nodes.

The margins: F_z - ``min_normal_force`` (> 0), the two faces of the friction cone
(mu + tol) F_z -+ F_x (>= 0, tol the nodes' :data:`~biped_casadi.simulation.validity.
FRICTION_TOL`) and U -+ u_i per torque (>= 0; left out with ``saturate`` or without a
finite limit).  Each is smooth where |F_x| or |u_i| is not (a kink at 0, far from its
bound).  Between two nodes the state is the RK4 step of length eta from the first.  Every
step is screened by the margins at its nodes (:func:`~biped_casadi.simulation.kernel.
screen_steps`, the running cycle's screen); where a margin may dip below 0 its rates in
eta at both ends of the step are taken (AD, exact) and its minimum located by Newton's
method on the rate (:func:`~biped_casadi.simulation.kernel.minima_between`).  A law
without derivatives (a compiled library, :mod:`~biped_casadi.simulation.compiled_loop`)
has the same screen; in a flagged step the margins are taken at
:data:`~biped_casadi.simulation.kernel.SUB_STEPS` (16) equal parts of it (each the RK4
step of that length from the first node), the parts screened alike, and a minimum
located by golden-section search on the margin's values
(:func:`~biped_casadi.simulation.kernel.minima_sampled`).  A minimum below its bound is
the first invalid state, named with "between two RK4 nodes".
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from ..numerics import FastCall
from .kernel import minima_between, minima_sampled, screen_steps
from .validity import FRICTION_TOL, node_message

__all__ = ["MarginCheck"]


class MarginCheck:
    """The margins of one simulator's limits, at its nodes and between them.

    Parameters
    ----------
    limits : Limits
        The thresholds.
    schema : Diagnostics
        The simulator's diagnostics rows.
    """

    def __init__(self, limits, schema):
        self.limits, self.schema = limits, schema
        nu = schema.nu
        self.status = ["negative_normal_force"]
        if np.isfinite(limits.mu):
            self.status += ["slipped"] * 2
        if not limits.saturate and np.isfinite(limits.torque_limit):
            self.status += ["torque_limit"] * (2 * nu)
        self._between = None

    def values(self, u, Fx, Fz, lib=np):
        """The margins from torques (nu, ...), F_x and F_z (numbers or CasADi with
        ``lib=ca``), stacked along the first axis."""
        lim = self.limits
        out = [Fz - lim.min_normal_force]
        if np.isfinite(lim.mu):
            cone = (lim.mu + FRICTION_TOL) * Fz
            out += [cone - Fx, cone + Fx]
        if "torque_limit" in self.status:
            U = lim.torque_limit
            out += [U - u[i] for i in range(self.schema.nu)] + \
                   [U + u[i] for i in range(self.schema.nu)]
        return lib.vertcat(*out) if lib is ca else np.array(out, float)

    def at_nodes(self, D) -> np.ndarray:
        """(n, m) margins at the n nodes of diagnostics D (rows x n)."""
        S = self.schema
        return self.values(S.row(D, "u"), S.row(D, "Fx"), S.row(D, "Fz")).T

    def build(self, rk4, margins):
        """``between(X, tau, eta, p) -> (W, dW/deta, d2W/deta2)`` on the RK4 step of
        length eta (built at first use): ``rk4`` the closed loop's step, ``margins(X,
        tau, p)`` the margins at a state."""
        if self._between is None:
            X = ca.SX.sym("X", rk4.size1_in(0))
            tau, eta = ca.SX.sym("tau"), ca.SX.sym("eta")
            p = ca.SX.sym("p", rk4.size1_in(3))
            Xe, te = rk4(X, tau, eta, p)
            W = margins(Xe, te, p)
            dW = ca.jacobian(W, eta)
            self._between = FastCall(ca.Function(
                "margins_between", [X, tau, eta, p], [W, dW, ca.jacobian(dW, eta)],
                ["X", "tau", "eta", "p"], ["W", "dW_deta", "d2W_deta2"]))
        return self._between

    def first_dip(self, between, W, steps, samples: int = 0):
        """The first minimum below its bound inside the steps, or None.

        Parameters
        ----------
        between : callable
            From :meth:`build`; with ``samples``, ``between(X, tau, eta, p) -> W`` (m,):
            the margins alone (a law without derivatives).
        W : numpy.ndarray
            (n, m) margins at consecutive nodes (up to three before the steps').
        steps : list of tuple
            (Xa, ta, length, p) of the last len(steps) steps between the rows of W.
        samples : int
            0: the minima located by their rates (:func:`~biped_casadi.simulation.
            kernel.minima_between`); else by the margins at this many equal parts of
            the step (:func:`~biped_casadi.simulation.kernel.minima_sampled`).

        Returns
        -------
        tuple or None
            (step index, eta, status) at the minimum.
        """
        base = len(W) - 1 - len(steps)
        near = screen_steps(W, np.zeros(W.shape[1]))[base:]
        for j in np.flatnonzero(near.any(axis=1)):
            Xa, ta, h, p = steps[j]

            def at(eta, Xa=Xa, ta=ta, p=p):
                return between(Xa, ta, eta, p)

            if samples:
                found = minima_sampled(near[j], at, h, W[base + j], W[base + j + 1], samples)
            else:
                r_a, r_b = (np.asarray(at(e)[1], float).ravel() for e in (0.0, h))
                found = minima_between(near[j], r_a, r_b, at, h)
            for eta, i, v in found:
                if v < 0 or (i == 0 and not v > 0):
                    return int(j), eta, self.status[i]
        return None

    def message(self, status, D, den_scale) -> str:
        """The failure in words at the state of diagnostics D (one column)."""
        node = {k: (v[..., 0] if isinstance(v, np.ndarray) else v)
                for k, v in self.schema.rows(D).items()}
        return (node_message(status, node, self.limits, den_scale)
                + ", between two RK4 nodes")
