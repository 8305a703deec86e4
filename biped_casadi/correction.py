"""Stride-to-stride correction v_c of paper eq. (17)-(18) (SPEC section 3).

Per output component, v_c is the fourth-order polynomial on [0, T/2] with
v_c(0) = y_i, dv_c(0) = dy_i and v_c = dv_c = ddv_c = 0 at T/2; v_c = 0 for tau >= T/2.
With sigma = tau / (T/2) the polynomial has a triple root at sigma = 1:

    v_c = (1 - sigma)^3 (y_i + (3 y_i + dy_i T/2) sigma)

so v_c is C^2 at T/2 (its third derivative jumps there, as the paper's footnote allows).
Works on numpy arrays and on CasADi symbols alike.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

__all__ = ["v_correction"]


def v_correction(tau, y_i, dy_i, T):
    """(v_c, dv_c/dtau, d2v_c/dtau2) at ``tau`` for initial output errors y_i, dy_i.

    numpy: tau scalar or array broadcast against y_i / dy_i; CasADi: symbolic in all
    arguments (``if_else`` switches to 0 for tau >= T/2).
    """
    half = T / 2
    sym = any(isinstance(a, (ca.SX, ca.MX)) for a in (tau, y_i, dy_i, T))
    sigma = tau / half
    a = y_i
    b = 3 * y_i + dy_i * half
    one = 1 - sigma
    v = one**3 * (a + b * sigma)
    # d/dsigma and d2/dsigma2 of (1-s)^3 (a + b s)
    dv_s = -3 * one**2 * (a + b * sigma) + one**3 * b
    ddv_s = 6 * one * (a + b * sigma) - 6 * one**2 * b
    dv = dv_s / half
    ddv = ddv_s / half**2
    if sym:
        inside = tau < half
        return (ca.if_else(inside, v, 0), ca.if_else(inside, dv, 0), ca.if_else(inside, ddv, 0))
    inside = np.asarray(tau) < half
    return (np.where(inside, v, 0.0), np.where(inside, dv, 0.0), np.where(inside, ddv, 0.0))
