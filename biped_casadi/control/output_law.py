"""The time-varying output law of the paper (§III), each equation written once.

Outputs v = M q with M = [M1, I] (eq. 5), so q_a = v - M1 q_u (eq. 10 with M2 = I).
The controller zeroes y_c = v - v^d(tau) - v_c(tau) (eq. 17) with the output dynamics of
eq. (13); the unactuated acceleration follows from the first row of eq. (1) (eq. 23), the
torques from the others (eq. 12).  The zero dynamics (eq. 19) is the same pair of
equations with y_c = 0.  Everything here works on numpy arrays and CasADi symbols alike
unless said otherwise; the controllers (:mod:`biped_casadi.control`), the simulator
and the Poincaré maps (:mod:`analysis`) call these functions and nothing else for these
equations.

Constants: :data:`SECTION` (the Poincaré section, docs: theory §4) and :data:`SINGULAR_RTOL`
(when the decoupling denominator of eq. (24) counts as vanishing).
"""
from __future__ import annotations

import math

from dataclasses import dataclass

import casadi as ca
import numpy as np

from ..numerics import as_number, as_vector
from ..results import Result

__all__ = ["SECTION", "SINGULAR_RTOL", "M1_LIMIT", "Gains", "SingularityReport", "check_M1",
           "check_rejoin", "output_matrix", "outputs", "coordinates_from_outputs",
           "initial_output_errors", "correction",
           "decoupling_denominator", "unactuated_acceleration", "actuated_torque",
           "output_acceleration", "singularity_report", "is_singular", "require_regular"]

#: Poincaré section tau = SECTION * T (docs: theory §4, paper §IV)
SECTION = 0.75

#: the decoupling denominator D11 - D12 M1 (eq. 24) "vanishes" on a step where its
#: smallest magnitude is below this fraction of its largest (or where it changes sign)
SINGULAR_RTOL = 1e-9

#: largest |M1(j)| the toolkit accepts.  In v = M1 q_u + q_a the actuated angles are lost
#: in round-off as |M1| grows: on RABBIT the two independent ways to A^z (variational
#: equation, AD through the map) agree to 5e-5 at |M1(j)| = 1e6, differ by 25 % at 1e8
#: and are meaningless (or overflow) beyond, so larger values are outside the model's
#: numerical validity and refused
M1_LIMIT = 1e6


def _symbolic(*args) -> bool:
    return any(isinstance(a, (ca.SX, ca.MX, ca.DM)) for a in args)


# ------------------------------------------------------------------ parameters
#: s: the largest time scale eps of the output PD
MAX_EPS = 10.0


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
        if self.eps > MAX_EPS:           # eps**2 overflowed (OverflowError) from 1e155 s
            raise ValueError(f"gain 'eps' = {self.eps!r} s is too large: at most {MAX_EPS:g} "
                             f"s (the outputs' time scale; beyond, tens of steps, the PD "
                             f"leaves them uncontrolled)")
        if not math.isfinite(self.Kp / max(self.eps**2, 1e-300)) or self.eps**2 == 0.0:
            raise ValueError(f"gain 'eps' = {self.eps!r} is too small: Kp / eps^2 overflows")

    def to_dict(self) -> dict:
        """The three gains by name.

        Returns
        -------
        dict
            ``Kp``, ``Kd``, ``eps``.
        """
        return dict(Kp=self.Kp, Kd=self.Kd, eps=self.eps)

    @property
    def stiffness(self) -> float:
        """The output dynamics' fastest rate times eps (1 for Kp = 1, Kd = 2).

        The largest magnitude of the roots of s^2 + Kd s + Kp."""
        disc = self.Kd**2 - 4.0 * self.Kp
        return 0.5 * (self.Kd + math.sqrt(disc)) if disc >= 0 else math.sqrt(self.Kp)

    @property
    def max_step(self) -> float:
        """The longest RK4 step that keeps the output dynamics stable with margin, s.

        eps / (2 stiffness): eps / 2 for Kp = 1, Kd = 2."""
        return self.eps / (2 * self.stiffness)

    def check_step(self, h: float, where: str = "h = T / rk4_steps") -> None:
        """Refuse an RK4 step too long for the output dynamics (they would diverge).

        RK4 integrates ddy = -Kd/eps dy - Kp/eps^2 y stably while h times its fastest
        rate stays below 2.78; the step must keep it below 1/2 (for Kp = 1, Kd = 2:
        eps >= 2 h).

        Parameters
        ----------
        h : float
            The integration step, s.
        where : str
            Names the step in the message.

        Raises
        ------
        ValueError
            One line naming the gains, the step and the longest step they allow.
        """
        k = self.stiffness
        if h > self.max_step:
            raise ValueError(
                f"the output gains (Kp, Kd, eps) = ({self.Kp:g}, {self.Kd:g}, {self.eps:g}) "
                f"make the closed loop too stiff for the integration step {where} = {h:.3g} "
                f"s: RK4 would diverge (eq. 13's output dynamics need eps >= {2 * k * h:.3g} s "
                f"at this step, or a step of at most {self.max_step:.3g} s: raise eps, "
                f"lower Kp or Kd, or take more RK4 steps per step)")


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

    Raises
    ------
    ValueError
        Wrong size, a non-finite component, or a component beyond :data:`M1_LIMIT`.
    """
    M1 = as_vector(M1, n, "M1")
    check_M1_range(M1)
    return M1


def check_M1_range(M1s, name: str = "M1"):
    """Refuse output matrices beyond the model's numerical validity (:data:`M1_LIMIT`).

    Parameters
    ----------
    M1s : array_like
        One M1, or many (any shape).
    name : str
        The argument's name, used in the error message.

    Raises
    ------
    ValueError
        Naming ``name`` when a component exceeds :data:`M1_LIMIT` in magnitude.
    """
    big = float(np.max(np.abs(M1s), initial=0.0))
    if big > M1_LIMIT:
        raise ValueError(f"{name}: components must lie within +-{M1_LIMIT:.0e}, got {big:.3g} "
                         "(beyond it round-off swamps q_a in the outputs v = M1 q_u + q_a "
                         "and A^z is meaningless)")


def check_rejoin(rejoin, name: str = "rejoin") -> float:
    """The rejoin time of v_c as a fraction of T, checked: a number in (0, SECTION].

    v_c (eq. 18) must vanish before the Poincaré section at SECTION T.

    Parameters
    ----------
    rejoin : float
        The time at which v_c rejoins the reference, as a fraction of T (the paper: 1/2).
    name : str
        The argument's name, used in the error message.

    Returns
    -------
    float

    Raises
    ------
    ValueError
        Naming ``name`` when it is not a number in (0, SECTION].
    """
    r = as_number(rejoin, name, positive=True)
    if r > SECTION:
        raise ValueError(f"{name} must be in (0, {SECTION}] (v_c must vanish before the "
                         f"Poincare section at {SECTION} T), got {rejoin!r}")
    return r


# ------------------------------------------------------------------ eq. (5), (10)
def output_matrix(M1) -> np.ndarray:
    """The output matrix M = [M1, I] of eq. (5) (numeric, M2 = I).

    Parameters
    ----------
    M1 : array_like
        (n,): one number per actuated joint.

    Returns
    -------
    numpy.ndarray
        Shape (n, n + 1).
    """
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

    Implements eqs. (10), (15), (16): q = (q_u, v - M1 q_u) with M2 = I; with
    v = v^d = M1 q_u^d + q_a^d (eq. 15) it is q_a = q_a^d + M1 (q_u^d - q_u), the
    configuration on the zero-dynamics manifold (first line of eq. 16), and with
    v = v^d + v_c that of the hybrid zero dynamics.

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
def initial_output_errors(M1, q, dq, q_d0, dq_d0):
    """The output error and its rate at the start of a step, where v_c starts (eq. 17).

    y_i = M q - v^d(0) and dy_i = M dq - dv^d(0), with M = [M1, I] and the reference at
    tau = 0.

    Parameters
    ----------
    M1 : array_like or casadi
        (nu,) outputs.
    q, dq : array_like or casadi
        The state just after the impact (or at the initial state), rad and rad/s.
    q_d0, dq_d0 : array_like or casadi
        The reference q^d(0) and dq^d(0).

    Returns
    -------
    tuple
        (y_i, dy_i), nu each.
    """
    return outputs(M1, q) - outputs(M1, q_d0), outputs(M1, dq) - outputs(M1, dq_d0)


def correction(tau, y_i, dy_i, t_c):
    """The stride-to-stride correction v_c and its two derivatives.

    Implements eq. (18).

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
        Output error y_i = v - v^d and its rate just after the impact (eq. 17).
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
        D11 - D12 M1, in kg m^2 (the units of D).
    """
    if _symbolic(D11, D12, M1):
        return D11 - ca.mtimes(D12, M1)
    return np.asarray(D11, float) - np.tensordot(np.asarray(M1, float), np.asarray(D12, float),
                                                 axes=(0, 0))


def unactuated_acceleration(D, H, M1, ddv):
    """The unactuated acceleration ddq_u = (-D12 ddv - H1) / (D11 - D12 M1).

    Implements eqs. (11), (14), (23): the first row of eq. (1), with D and H split as in
    eq. (11), written in the outputs (the first line of eq. 12) and solved for ddq_u.
    With ddv = ddv^d it is the swing-phase zero dynamics of eq. (14) (second line; the
    same with q_a from eq. 16); with ddv = ddv^d + ddv_c it is the hybrid zero dynamics
    that the restricted Poincaré map integrates (eq. 19).

    Parameters
    ----------
    D, H : casadi
        Mass matrix (nq x nq) and C dq + G (nq x 1) at the current state.
    M1 : casadi column or numbers
        The output matrix's first column (nu).
    ddv : casadi column
        Output acceleration (nu), rad/s^2.

    Returns
    -------
    casadi
        ddq_u, rad/s^2 (infinite where D11 - D12 M1 = 0, eq. 24).
    """
    den = decoupling_denominator(D[0, 0], D[0, 1:], M1)
    return (-ca.mtimes(D[0, 1:], ddv) - H[0]) / den


def actuated_torque(D, H, M1, ddq_u, ddv):
    """The torques u = (D21 - D22 M1) ddq_u + D22 ddv + H2.

    Implements eq. (12): its second line, rows 2.. of eq. (1) with B = [0; I], given
    ddq_u from the first line (:func:`unactuated_acceleration`, eq. 23).

    Parameters
    ----------
    D, H : casadi
        Mass matrix (nq x nq) and C dq + G (nq x 1) at the current state.
    M1 : casadi column or numbers
        The output matrix's first column (nu).
    ddq_u : casadi
        Unactuated acceleration (eq. 23), rad/s^2.
    ddv : casadi column
        Output acceleration (nu), rad/s^2.

    Returns
    -------
    casadi
        Torques u (nu), N m.
    """
    D21, D22 = D[1:, 0], D[1:, 1:]
    return ca.mtimes(D21 - ca.mtimes(D22, M1), ddq_u) + ca.mtimes(D22, ddv) + H[1:]


def output_acceleration(ddv_target, y, dy, gains: Gains):
    """The commanded output acceleration ddv = ddv_target - Kd/eps dy - Kp/eps^2 y.

    Implements eq. (13), with ddv_target = ddv^d + ddv_c and y, dy the outputs y_c of
    eq. (17) and their rates.

    Parameters
    ----------
    ddv_target : array or casadi
        The outputs' reference acceleration (nu), rad/s^2.
    y, dy : array or casadi
        Output error (rad) and its rate (rad/s).
    gains : Gains
        Kp, Kd and eps.

    Returns
    -------
    array or casadi
        ddv (nu), rad/s^2.
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
    # signs, not the product of the extremes (which overflows for huge values)
    changes = np.sign(d.min(axis)) * np.sign(d.max(axis)) <= 0
    return changes | (mag.min(axis) < SINGULAR_RTOL * mag.max(axis))


@dataclass
class SingularityReport(Result):
    """Whether a controller is singular along the reference step.

    For the time-varying controller the sampled quantity is the decoupling denominator
    D11 - D12 M1 (eq. 23-24); for virtual constraints its analogue.  ``success`` means
    the denominator was sampled; the verdict is ``status`` (``singular``).

    Parameters
    ----------
    min_abs : float
        Smallest magnitude of the denominator on the step.
    min_value, max_value : float
        Its smallest and largest value.
    changes_sign : bool
        Whether it changes sign (or touches 0) on the step.
    status : {'regular', 'singular'}
        'singular' when :func:`is_singular` says so.
    message : str
        Why it is singular (empty when regular).
    """

    min_abs: float
    min_value: float
    max_value: float
    changes_sign: bool
    status: str = "regular"
    message: str = ""

    SUCCESS = ("regular", "singular")

    @property
    def singular(self) -> bool:
        """True when the controller is singular on the step."""
        return self.status == "singular"


def require_regular(controller, M1, where: str = "the reference step") -> None:
    """Refuse a time-varying controller that is singular on its step (eq. 24).

    Parameters
    ----------
    controller : TimeVaryingController
        The controller (its :meth:`singularity` report decides).
    M1 : array_like
        Its outputs, for the message.
    where : str
        Names the step in the message.

    Raises
    ------
    ValueError
        One line naming M1, when D11 - D12 M1 vanishes or changes sign on the step.
    """
    if controller.singularity().singular:
        raise ValueError(f"M1 = {list(np.ravel(M1).tolist())} makes the controller singular "
                         f"on {where} (D11 - D12 M1 vanishes, eq. 24)")


def singularity_report(values) -> SingularityReport:
    """:class:`SingularityReport` of denominator samples along a step.

    Parameters
    ----------
    values : array_like
        The denominator at points of the step.

    Returns
    -------
    SingularityReport
        Its extremes, whether it changes sign, and the status.
    """
    d = np.asarray(values, dtype=float).ravel()
    sing = bool(is_singular(d))
    changes = bool(np.sign(d.min()) * np.sign(d.max()) <= 0)
    msg = ("the decoupling denominator (eq. 24) vanishes or changes sign on the step"
           if sing else "")
    return SingularityReport(min_abs=float(np.min(np.abs(d))), min_value=float(d.min()),
                             max_value=float(d.max()), changes_sign=changes,
                             status="singular" if sing else "regular", message=msg)
