"""Torque saturation: the one rule by which every saturating path clips a law's torques
(the walking simulator with ``SimulationOptions(saturate=True)``, the running
controller's :meth:`~biped_casadi.control.running.RunningController.applied`, the C
exports with ``--saturate`` and the Python laws they are checked against).

A torque beyond the limit becomes the limit, an infinite request too (as numpy's
``clip``); a NaN stays NaN.  CasADi's ``fmin``/``fmax`` would turn a NaN into a finite
torque, hiding a law that failed: kept, it stops a simulation at its not-finite state
and makes a C export return its not-finite code.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

__all__ = ["clip_torques", "beyond_limit"]


def _limit_of(limit, u):
    """``limit`` as given (a number), or per torque as a column of ``u``'s kind and rows."""
    if np.ndim(limit) == 0:
        return limit
    if isinstance(u, (ca.SX, ca.MX, ca.DM)):
        return ca.DM(np.asarray(limit, float))
    return np.asarray(limit, float).reshape((-1,) + (1,) * (np.ndim(u) - 1))


def clip_torques(u, limit):
    """The torques ``u`` clipped at +-``limit``, a NaN kept.

    Parameters
    ----------
    u : casadi.SX, casadi.MX, casadi.DM or array_like
        The law's torques (nu, ...).
    limit : float or sequence of float
        The bound, N m (``inf``: ``u`` unchanged), or one bound per torque (nu numbers,
        u1 .. u_nu, :attr:`~biped_casadi.model.description.RobotDescription.torque_bound`).

    Returns
    -------
    Same kind as ``u`` (a numpy array for array_like)
        Each torque above its ``limit`` (+inf included) is the limit, each below
        ``-limit`` is ``-limit``, any other (NaN included) is itself.
    """
    limit = _limit_of(limit, u)
    if isinstance(u, (ca.SX, ca.MX, ca.DM)):
        # comparisons with a NaN are false: it falls through both branches unchanged
        return ca.if_else(u > limit, limit, ca.if_else(u < -limit, -limit, u))
    return np.clip(u, -limit, limit)


def beyond_limit(u, limit):
    """Whether some ``|u_i|`` exceeds its limit (a NaN does not).

    Parameters
    ----------
    u : casadi.SX, casadi.MX, casadi.DM or array_like
        Torques of one instant (nu numbers).
    limit : float or sequence of float
        As :func:`clip_torques`.

    Returns
    -------
    casadi expression or float
        1 or 0 (a CasADi value for a CasADi ``u``).
    """
    if isinstance(u, (ca.SX, ca.MX, ca.DM)):
        if np.ndim(limit) == 0:
            return ca.mmax(ca.fabs(u)) > limit
        return ca.mmax(ca.fabs(u) - _limit_of(limit, u)) > 0
    if np.ndim(limit) == 0:
        return float(np.max(np.abs(u)) > limit)
    return float(np.any(np.abs(np.asarray(u, float).ravel()) > np.asarray(limit, float)))
