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

__all__ = ["clip_torques"]


def clip_torques(u, limit: float):
    """The torques ``u`` clipped at +-``limit``, a NaN kept.

    Parameters
    ----------
    u : casadi.SX, casadi.MX, casadi.DM or array_like
        The law's torques.
    limit : float
        The bound, N m (``inf``: ``u`` unchanged).

    Returns
    -------
    Same kind as ``u`` (a numpy array for array_like)
        Each torque above ``limit`` (+inf included) is ``limit``, each below
        ``-limit`` is ``-limit``, any other (NaN included) is itself.
    """
    if isinstance(u, (ca.SX, ca.MX, ca.DM)):
        # comparisons with a NaN are false: it falls through both branches unchanged
        return ca.if_else(u > limit, limit, ca.if_else(u < -limit, -limit, u))
    return np.clip(u, -limit, limit)
