"""The full-order closed loop driven by a compiled controller library.

A :class:`~biped_casadi.control.compiled.CompiledController` is numeric only (its law is
C code behind ctypes), so the simulator cannot compose it with the plant symbolically
(nor its Python twin :class:`~biped_casadi.control.compiled.PythonTwin`, the same calls
answered by CasADi).
Here the same closed loop is built from numeric calls: every RK4 stage asks the library
for the torques (``biped_torque``) and the plant for the accelerations (eq. 1), the
stages are combined by :func:`~biped_casadi.numerics.rk4_step`, and the diagnostics of
every node come from ``biped_outputs`` and the plant's kinematics and ground reaction,
in the simulator's schema.  The impact time is found by the simulator's safeguarded
Newton iteration with the swing foot's vertical velocity at the end of the last RK4
step as the slope (the exact derivative of that step would need the library's
derivatives; with this slope Newton converges to the same root, |z_sw| < 1e-15 m, in one
or two more iterations); the swing foot's minima between two nodes are located by
bisection on that velocity.  The stance force, the friction cone and the torques between
the nodes are screened as for a CasADi law and, where they may dip, sampled inside the
step and their minima located from values alone (:mod:`~biped_casadi.simulation.
margins`).

:func:`compiled_closed_loop` returns the callables :class:`~biped_casadi.simulation.
Simulator` uses in place of its CasADi blocks.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from ..control.saturation import beyond_limit, clip_torques
from ..numerics import FastCall, rk4_step

__all__ = ["compiled_closed_loop"]


def _diagnostics_function(plant, schema, n):
    """Diagnostics of n nodes from (q, dq, applied u, den, y, dy, in_range, saturated)."""
    nq, nu = plant.nq, plant.nu
    q, dq, u = ca.SX.sym("q", nq), ca.SX.sym("dq", nq), ca.SX.sym("u", nu)
    den, y, dy = ca.SX.sym("den"), ca.SX.sym("y", nu), ca.SX.sym("dy", nu)
    inr, sat = ca.SX.sym("in_range"), ca.SX.sym("saturated")
    Fx, Fz = plant.ground_reaction(q, dq, u)
    f = ca.Function("compiled_loop_diagnostics", [q, dq, u, den, y, dy, inr, sat],
                    [schema.vector(plant, q, dq, u, Fx, Fz, den, y, dy, inr, sat)])
    return FastCall(f.map(n) if n > 1 else f)


class _NumericLoop:
    """The closed loop of a numeric law: RK4 steps, node diagnostics, the strike event."""

    def __init__(self, controller, plant, schema, limits, saturate, block_sizes):
        self.c, self.nq, self.nu = controller, plant.nq, plant.nu
        self.saturate, self.limit = saturate, limits.torque_limit
        self.fd = FastCall(plant.forward_dynamics)
        self.foot = FastCall(_foot(plant))
        self.diag = {n: _diagnostics_function(plant, schema, n) for n in set(block_sizes) | {1}}

    def applied(self, u):
        """The torques the plant receives, and whether they were clipped."""
        if not self.saturate:
            return u, 0.0
        return clip_torques(u, self.limit), beyond_limit(u, self.limit)

    def step(self, X, tau, h, p, u0=None):
        """One RK4 step; u0: the torques at (X, tau) when already known."""
        nq = self.nq

        def rhs(Xv, c):
            q, dq = Xv[:nq], Xv[nq:2 * nq]
            u = u0 if (c == 0.0 and u0 is not None) else self.c.torque(tau + c * h, q, dq, p)[1]
            return np.r_[dq, self.fd(q, dq, self.applied(u)[0])[0].ravel()]
        return rk4_step(rhs, X, h)

    def node(self, X, tau, p):
        """The law's torques and outputs at a node."""
        q, dq = X[:self.nq], X[self.nq:2 * self.nq]
        rc, u = self.c.torque(tau, q, dq, p)          # NaN where tau is out of range
        _, y, dy, den = self.c.outputs(tau, q, dq, p)
        return u, y, dy, den, 0.0 if rc == 2 else 1.0

    def columns(self, Xs, taus, p):
        """Diagnostics of the nodes (the columns of Xs)."""
        n, nq, nu = Xs.shape[1], self.nq, self.nu
        law = [self.node(Xs[:, k], taus[k], p) for k in range(n)]
        ua = [self.applied(v[0]) for v in law]
        Ua = np.array([a[0] for a in ua]).T.reshape(nu, n)
        sat = np.array([[a[1] for a in ua]])
        den, Y, dY, inr = (np.array([v[k] for v in law], dtype=float).T.reshape(-1, n)
                           for k in (3, 1, 2, 4))
        return self.diag[n](Xs[:nq], Xs[nq:2 * nq], Ua, den, Y, dY, inr, sat)[0]

    def block(self, n):
        """``block(X, tau, h, p) -> (X_nodes, tau_nodes, diag)`` of n RK4 steps."""
        nq = self.nq

        def run(X, tau0, h, p):
            X = np.asarray(X, float).ravel().copy()
            tau, h, p = float(tau0), float(h), np.asarray(p, float).ravel()
            Xs, taus = np.empty((X.size, n)), np.empty(n)
            u0 = None
            for k in range(n):
                X = self.step(X, tau, h, p, u0)
                tau = tau + h
                Xs[:, k], taus[k] = X, tau
                u0 = self.c.torque(tau, X[:nq], X[nq:2 * nq], p)[1]
            return Xs, taus[None, :], self.columns(Xs, taus, p)
        return run

    def diagnostics(self, X, tau, p):
        """``[diag]`` at one state."""
        X = np.asarray(X, float).ravel()
        return [self.columns(X[:, None], np.array([float(tau)]), np.asarray(p, float).ravel())]

    def event(self, X, tau, eta, p):
        """(z_sw, dz_sw/dt, X) at the end of a last RK4 step of length eta."""
        X = np.asarray(X, float).ravel()
        Xe = self.step(X, float(tau), float(eta), np.asarray(p, float).ravel())
        _, z, dz = self.foot(Xe[:self.nq], Xe[self.nq:2 * self.nq])
        return z, dz, Xe[:, None]

    def dip(self, X, tau, eta, p):
        """(z_sw, its slope, 0, x_sw, X) at the end of a last RK4 step of length eta: the
        slope is the foot's vertical velocity there and no curvature is given, so that
        Newton's method on the slope bisects (module docstring)."""
        X = np.asarray(X, float).ravel()
        Xe = self.step(X, float(tau), float(eta), np.asarray(p, float).ravel())
        x, z, dz = self.foot(Xe[:self.nq], Xe[self.nq:2 * self.nq])
        return z, dz, np.zeros((1, 1)), x, Xe[:, None]


def compiled_closed_loop(controller, plant, schema, limits, saturate, block_sizes):
    """The simulator's closed-loop callables for a numeric law.

    Parameters
    ----------
    controller : NumericLaw
        A compiled library or its Python twin (``torque``, ``outputs``, ``n_par``).
    plant : BipedModel
        The robot that moves.
    schema : Diagnostics
        The simulator's diagnostics rows (with outputs).
    limits : Limits
        The run's limits (``torque_limit``).
    saturate : bool
        Clip the torques the plant receives at the limit (``SimulationOptions.saturate``).
    block_sizes : tuple of int
        The nodes of the simulator's two blocks (a step's first block, a quarter).

    Returns
    -------
    tuple
        (first block, quarter block, diagnostics, event, impact map, dip), called as the
        simulator's: ``block(X, tau, h, p) -> (X_nodes, tau_nodes, diag)``,
        ``diagnostics(X, tau, p) -> [diag]``, ``event(X, tau, eta, p) -> (z_sw, slope,
        X_event)``, ``impact(q, dq) -> impact_full``, ``dip(X, tau, eta, p) -> (z_sw,
        slope, curvature, x_sw, X_event)``.
    """
    loop = _NumericLoop(controller, plant, schema, limits, saturate, block_sizes)
    first, quarter = (loop.block(n) for n in block_sizes)
    return (first, quarter, loop.diagnostics, loop.event, FastCall(plant.impact_full),
            loop.dip)


def _foot(plant):
    """(q, dq) -> (x_sw, z_sw, dz_sw/dt)."""
    q, dq = ca.SX.sym("q", plant.nq), ca.SX.sym("dq", plant.nq)
    x, z = plant.swing_foot(q)
    _, dz = plant.swing_foot_velocity(q, dq)
    return ca.Function("compiled_loop_foot", [q, dq], [x, z, dz], ["q", "dq"],
                       ["x_sw", "z_sw", "dz_sw"])
