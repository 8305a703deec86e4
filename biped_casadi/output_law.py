"""The time-varying output law of the paper (§III), each equation written once.

Outputs v = M q with M = [M1, I] (eq. 5), so q_a = v - M1 q_u (eq. 10 with M2 = I).
The controller zeroes y_c = v - v^d(tau) - v_c(tau) (eq. 17) with the output dynamics of
eq. (13); the unactuated acceleration follows from the first row of eq. (1) (eq. 23), the
torques from the others (eq. 12).  The zero dynamics (eq. 19) is the same pair of
equations with y_c = 0.  Everything here works on numpy arrays and CasADi symbols alike
unless said otherwise; the controllers (:mod:`biped_casadi.controllers`), the simulator
and the Poincaré maps (:mod:`analysis`) call these functions and nothing else for these
equations.

Constants: :data:`SECTION` (the Poincaré section, SPEC §4) and :data:`SINGULAR_RTOL`
(when the decoupling denominator of eq. (24) counts as vanishing).
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from .numerics import as_number, as_vector
from .results import Result

__all__ = ["SECTION", "SINGULAR_RTOL", "Gains", "SingularityReport", "check_M1",
           "output_matrix", "outputs", "coordinates_from_outputs", "correction",
           "decoupling_denominator", "unactuated_acceleration", "actuated_torque",
           "output_acceleration", "singularity_report", "is_singular"]

#: Poincaré section tau = SECTION * T (SPEC §4, paper §IV)
SECTION = 0.75

#: the decoupling denominator D11 - D12 M1 (eq. 24) "vanishes" on a step where its
#: smallest magnitude is below this fraction of its largest (or where it changes sign)
SINGULAR_RTOL = 1e-9


def _symbolic(*args) -> bool:
    return any(isinstance(a, (ca.SX, ca.MX, ca.DM)) for a in args)


# ------------------------------------------------------------------ parameters
@dataclass(frozen=True)
class Gains:
    """PD gains of the output dynamics, eq. (13): ddy = -Kd/eps dy - Kp/eps^2 y.

    Parameters
    ----------
    Kp, Kd : float
        Positive gains.
    eps : float
        Positive time scale; small eps = high gain, the closed loop approaches its zero
        dynamics.
    """

    Kp: float = 1.0
    Kd: float = 2.0
    eps: float = 0.02

    def __post_init__(self):
        for name in ("Kp", "Kd", "eps"):
            object.__setattr__(self, name, as_number(getattr(self, name), f"gain {name!r}",
                                                     positive=True))

    def to_dict(self) -> dict:
        """The three gains by name."""
        return dict(Kp=self.Kp, Kd=self.Kd, eps=self.eps)


def check_M1(M1, n: int = 4) -> np.ndarray:
    """``M1`` as a finite vector of ``n`` components (``ValueError`` naming M1 otherwise).

    Parameters
    ----------
    M1 : array_like
        The output matrix's first column block (one number per actuated joint).
    n : int
        Number of actuated joints.

    Returns
    -------
    numpy.ndarray
        Shape (n,).
    """
    return as_vector(M1, n, "M1")


# ------------------------------------------------------------------ eq. (5), (10)
def output_matrix(M1) -> np.ndarray:
    """M = [M1, I] of eq. (5) (numeric), shape (n, n + 1)."""
    M1 = np.asarray(M1, dtype=float).ravel()
    return np.hstack([M1[:, None], np.eye(M1.size)])


def outputs(M1, q):
    """Controlled outputs v = M q = M1 q_u + q_a (M2 = I).

    Implements eqs. (5), (8), (21): applied to q^d, dq^d, ddq^d it gives the reference
    outputs v^d and their derivatives.

    Parameters
    ----------
    M1 : array_like or casadi
        (n,) numbers or a CasADi column.
    q : array_like or casadi
        Coordinates (n + 1,) or (n + 1, N) (numpy), or CasADi (n + 1) x N; also applies
        to velocities and accelerations (M is constant).

    Returns
    -------
    numpy.ndarray or casadi
        v, shape (n,) or (n, N).
    """
    if _symbolic(M1, q):
        M1 = ca.DM(M1) if isinstance(M1, (np.ndarray, list, tuple)) else M1
        return ca.mtimes(M1, q[0, :]) + q[1:, :]
    q = np.asarray(q, dtype=float)
    M1 = np.asarray(M1, dtype=float)
    if q.ndim == 1:
        return M1 * q[0] + q[1:]
    return M1[:, None] * q[0][None, :] + q[1:]


def coordinates_from_outputs(M1, q_u, v):
    """The configuration from the unactuated coordinate and the outputs.

    Implements eqs. (10), (16): q = (q_u, v - M1 q_u) with M2 = I; with v = v^d (+ v_c)
    it is the configuration on the zero-dynamics manifold.

    Parameters
    ----------
    M1 : array_like or casadi
        (n,) numbers or a CasADi column.
    q_u : float or casadi
        The unactuated coordinate (or its rate, with v the output rates).
    v : array_like or casadi
        The outputs.

    Returns
    -------
    numpy.ndarray or casadi
        q, n + 1 components.
    """
    if _symbolic(M1, q_u, v):
        M1 = ca.DM(M1) if isinstance(M1, (np.ndarray, list, tuple)) else M1
        return ca.vertcat(q_u, v - M1 * q_u)
    return np.r_[q_u, np.asarray(v, float) - np.asarray(M1, float) * q_u]


# ------------------------------------------------------------------ eq. (17)-(18)
def correction(tau, y_i, dy_i, t_c):
    """The stride-to-stride correction v_c and its two derivatives.

    Implements eqs. (17), (18).

    Per output component, v_c is the fourth-order polynomial on [0, t_c] with
    v_c(0) = y_i, dv_c(0) = dy_i and v_c = dv_c = ddv_c = 0 at t_c; v_c = 0 for
    tau >= t_c.  The paper rejoins at t_c = T/2.  With sigma = tau / t_c the polynomial
    has a triple root at sigma = 1,

        v_c = (1 - sigma)^3 (y_i + (3 y_i + dy_i t_c) sigma),

    so v_c is C^2 at t_c (its third derivative jumps there, as the paper's footnote
    allows).

    Parameters
    ----------
    tau : float, array or casadi
        Time since the start of the step.
    y_i, dy_i : array or casadi
        Output error and its rate just after the impact (eq. 17).
    t_c : float or casadi
        Rejoin time (> 0).

    Returns
    -------
    tuple
        (v_c, dv_c/dtau, d2v_c/dtau2); numpy broadcasts ``tau`` against y_i, dy_i;
        CasADi switches to 0 for tau >= t_c with ``if_else``.
    """
    sigma = tau / t_c
    a = y_i
    b = 3 * y_i + dy_i * t_c
    one = 1 - sigma
    v = one**3 * (a + b * sigma)
    dv = (-3 * one**2 * (a + b * sigma) + one**3 * b) / t_c
    ddv = (6 * one * (a + b * sigma) - 6 * one**2 * b) / t_c**2
    if _symbolic(tau, y_i, dy_i, t_c):
        inside = tau < t_c
        return ca.if_else(inside, v, 0), ca.if_else(inside, dv, 0), ca.if_else(inside, ddv, 0)
    inside = np.asarray(tau) < t_c
    return np.where(inside, v, 0.0), np.where(inside, dv, 0.0), np.where(inside, ddv, 0.0)


# ------------------------------------------------------------------ eq. (12), (13), (23), (24)
def decoupling_denominator(D11, D12, M1):
    """D11 - D12 M1: the controller is singular where it vanishes.

    Implements eq. (24).

    Parameters
    ----------
    D11 : float, array (N,) or casadi
        First diagonal entry of the mass matrix.
    D12 : array (n,), (n, N) or casadi row (1 x n)
        The rest of its first row.
    M1 : array (n,) or casadi column
        The output matrix's first column.

    Returns
    -------
    float, numpy.ndarray (N,) or casadi
    """
    if _symbolic(D11, D12, M1):
        return D11 - ca.mtimes(D12, M1)
    return np.asarray(D11, float) - np.tensordot(np.asarray(M1, float), np.asarray(D12, float),
                                                 axes=(0, 0))


def unactuated_acceleration(D, H, M1, ddv):
    """ddq_u = (-D12 ddv - H1) / (D11 - D12 M1): the first row of eq. (1) written in
    the outputs.

    Implements eqs. (11), (23), and the first line of eq. (12); with ddv = ddv^d the
    zero dynamics of eq. (14), with ddv = ddv^d + ddv_c that of eq. (19).

    Parameters
    ----------
    D, H : casadi
        Mass matrix and C dq + G at the current state.
    M1 : casadi column or numbers
    ddv : casadi column
        Output acceleration.

    Returns
    -------
    casadi
        ddq_u.
    """
    den = decoupling_denominator(D[0, 0], D[0, 1:], M1)
    return (-ca.mtimes(D[0, 1:], ddv) - H[0]) / den


def actuated_torque(D, H, M1, ddq_u, ddv):
    """u = (D21 - D22 M1) ddq_u + D22 ddv + H2: rows 2.. of eq. (1) with B = [0; I].

    Implements eq. (12) (second line).

    Parameters
    ----------
    D, H : casadi
        Mass matrix and C dq + G.
    M1 : casadi column or numbers
    ddq_u : casadi
        Unactuated acceleration (eq. 23).
    ddv : casadi column
        Output acceleration.

    Returns
    -------
    casadi
        Torques u.
    """
    D21, D22 = D[1:, 0], D[1:, 1:]
    return ca.mtimes(D21 - ca.mtimes(D22, M1), ddq_u) + ca.mtimes(D22, ddv) + H[1:]


def output_acceleration(ddv_target, y, dy, gains: Gains):
    """ddv = ddv_target - Kd/eps dy - Kp/eps^2 y, with ddv_target = ddv^d + ddv_c and
    y, dy the outputs of eq. (17).

    Implements eq. (13).

    Parameters
    ----------
    ddv_target : array or casadi
        The outputs' reference acceleration.
    y, dy : array or casadi
        Output error and its rate.
    gains : Gains

    Returns
    -------
    array or casadi
        The commanded output acceleration.
    """
    return ddv_target - gains.Kd / gains.eps * dy - gains.Kp / gains.eps**2 * y


# ------------------------------------------------------------------ singularity
def is_singular(values, axis: int = -1):
    """Whether a denominator sampled along a step vanishes or changes sign.

    Parameters
    ----------
    values : array_like
        Samples of the denominator (eq. 24), along ``axis``.
    axis : int
        The axis of the samples.

    Returns
    -------
    bool or numpy.ndarray of bool
        True where the values change sign (or touch 0) or where the smallest magnitude is
        below :data:`SINGULAR_RTOL` of the largest.
    """
    d = np.asarray(values, dtype=float)
    mag = np.abs(d)
    return (d.min(axis) * d.max(axis) <= 0) | (mag.min(axis) < SINGULAR_RTOL * mag.max(axis))


@dataclass
class SingularityReport(Result):
    """The decoupling denominator along the reference step (eq. 23-24 for the
    time-varying controller).  ``status`` is 'regular' or 'singular'; ``success`` means
    regular."""

    min_abs: float
    min_value: float
    max_value: float
    changes_sign: bool
    status: str = "regular"
    message: str = ""

    SUCCESS = ("regular",)

    @property
    def singular(self) -> bool:
        """True when the controller is singular on the step."""
        return self.status == "singular"


def singularity_report(values) -> SingularityReport:
    """:class:`SingularityReport` of denominator samples along a step.

    Parameters
    ----------
    values : array_like
        The denominator at points of the step.

    Returns
    -------
    SingularityReport
    """
    d = np.asarray(values, dtype=float).ravel()
    sing = bool(is_singular(d))
    changes = bool(d.min() * d.max() <= 0)
    msg = ("the decoupling denominator (eq. 24) vanishes or changes sign on the step"
           if sing else "")
    return SingularityReport(min_abs=float(np.min(np.abs(d))), min_value=float(d.min()),
                             max_value=float(d.max()), changes_sign=changes,
                             status="singular" if sing else "regular", message=msg)
