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
or two more iterations).

:func:`compiled_closed_loop` returns the callables :class:`~biped_casadi.simulation.
Simulator` uses in place of its CasADi blocks.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

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
        (first block, quarter block, diagnostics, event, impact map), called as the
        simulator's: ``block(X, tau, h, p) -> (X_nodes, tau_nodes, diag)``,
        ``diagnostics(X, tau, p) -> [diag]``, ``event(X, tau, eta, p) -> (z_sw, slope,
        X_event)``, ``impact(q, dq) -> impact_full``.
    """
    nq, nu = plant.nq, plant.nu
    fd = FastCall(plant.forward_dynamics)
    foot = FastCall(_foot(plant))
    limit = limits.torque_limit
    diag = {n: _diagnostics_function(plant, schema, n) for n in set(block_sizes) | {1}}

    def applied(u):
        if not saturate:
            return u, 0.0
        return np.clip(u, -limit, limit), float(np.max(np.abs(u)) > limit)

    def accel(X, tau, p, u=None):
        q, dq = X[:nq], X[nq:2 * nq]
        if u is None:
            u = controller.torque(tau, q, dq, p)[1]
        return np.r_[dq, fd(q, dq, applied(u)[0])[0].ravel()]

    def step(X, tau, h, p, u0=None):
        """One RK4 step; u0: the torques at (X, tau) when already known."""
        def rhs(Xv, c):
            return accel(Xv, tau + c * h, p, u0 if c == 0.0 else None)
        return rk4_step(rhs, X, h)

    def node(X, tau, p):
        """The law's torques and outputs at a node."""
        q, dq = X[:nq], X[nq:2 * nq]
        rc, u = controller.torque(tau, q, dq, p)
        rco, y, dy, den = controller.outputs(tau, q, dq, p)
        if rc == 2:               # tau or the phase outside the reference: no torques
            u = np.full(nu, np.nan)
        return u, y, dy, den, 0.0 if rc == 2 or rco == 2 else 1.0

    def columns(Xs, taus, p):
        """Diagnostics of the nodes (columns of Xs) and the torques there."""
        n = Xs.shape[1]
        law = [node(Xs[:, k], taus[k], p) for k in range(n)]
        U = np.array([v[0] for v in law]).T.reshape(nu, n)
        ua = [applied(U[:, k]) for k in range(n)]
        Ua = np.array([a[0] for a in ua]).T.reshape(nu, n)
        sat = np.array([[a[1] for a in ua]])
        cols = [np.array([v[k] for v in law], dtype=float).T.reshape(-1, n) for k in (3, 1, 2, 4)]
        den, Y, dY, inr = cols
        D = diag[n](Xs[:nq], Xs[nq:2 * nq], Ua, den, Y, dY, inr, sat)[0]
        return D, U

    def block_of(n):
        def block(X, tau0, h, p):
            X = np.asarray(X, float).ravel().copy()
            tau, h, p = float(tau0), float(h), np.asarray(p, float).ravel()
            Xs, taus = np.empty((X.size, n)), np.empty(n)
            u0 = None
            for k in range(n):
                X = step(X, tau, h, p, u0)
                tau = tau + h
                Xs[:, k], taus[k] = X, tau
                u0 = controller.torque(tau, X[:nq], X[nq:2 * nq], p)[1]
            D, _ = columns(Xs, taus, p)
            return Xs, taus[None, :], D
        return block

    def diagnostics(X, tau, p):
        X = np.asarray(X, float).ravel()
        return [columns(X[:, None], np.array([float(tau)]), np.asarray(p, float).ravel())[0]]

    def event(X, tau, eta, p):
        X = np.asarray(X, float).ravel()
        Xe = step(X, float(tau), float(eta), np.asarray(p, float).ravel())
        z, dz = foot(Xe[:nq], Xe[nq:2 * nq])
        return z, dz, Xe[:, None]

    impact = FastCall(plant.impact_full)
    first, quarter = (block_of(n) for n in block_sizes)
    return first, quarter, diagnostics, event, impact


def _foot(plant):
    """(q, dq) -> (z_sw, dz_sw/dt)."""
    q, dq = ca.SX.sym("q", plant.nq), ca.SX.sym("dq", plant.nq)
    _, z = plant.swing_foot(q)
    _, dz = plant.swing_foot_velocity(q, dq)
    return ca.Function("compiled_loop_foot", [q, dq], [z, dz], ["q", "dq"], ["z_sw", "dz_sw"])
