"""Closed-loop controllers for walking: the time-varying output controller of the paper
(§III, eq. 12-13, 17) and, for the comparison of §V-C, a virtual-constraint (hybrid zero
dynamics) controller fitted to the same reference.

Both controllers are CasADi Functions built once per controller object, written against
the reference interface of :mod:`biped_casadi.reference`, and share one interface used
by :mod:`biped_casadi.simulate`:

``law(q, dq, tau, r, p) -> (u, y, dy, den, dr, in_range)``
    torques u, outputs y and their rates dy, the decoupling denominator ``den`` (zero
    where the controller is singular), the time derivative ``dr`` of the reference
    state r, and ``in_range`` (1 while the reference is defined at the current state).
``step_start(q, dq) -> StepStart(r, p)``
    the reference state r and the per-step constants p at the start of a step (just
    after an impact, or at the initial state).

Reference state r.  The time-varying controller needs q_u^d(tau); a gait defines it as
the solution of the unactuated row of eq. (1) with q_a = q_a^d(tau) (SPEC §2), carried
as the reference state r = (q_u^d, dq_u^d) and reset to its value at tau = 0 at every
impact: a function of tau alone, so the hybrid closed loop is still the system in
(q, dq, tau) of eq. (9).
"""
from __future__ import annotations

import abc
import hashlib
import math
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from .numerics import as_number, as_vector
from .output_law import (SECTION, Gains, SingularityReport, actuated_torque, check_M1,
                         correction, decoupling_denominator, output_acceleration,
                         output_matrix, outputs, singularity_report, unactuated_acceleration)
from .reference import require_same_robot

__all__ = ["Gains", "StepStart", "ControlOutput", "SingularityReport",
           "TimeVaryingController", "VirtualConstraints", "VirtualConstraintController",
           "fit_virtual_constraints", "HIP_PHASE", "PAPER_REJOIN"]

#: RABBIT's phase variable c of the virtual-constraint controller, theta = c q: the angle
#: of the line stance foot -> hip from the vertical, exactly q1 + q2 / 2 when tibia and
#: femur are equally long.  Every model has its own (``model.hip_phase``, the default).
HIP_PHASE = (1.0, 0.5, 0.0, 0.0, 0.0)

#: the paper's rejoin time of the correction v_c, as a fraction of T (eq. 18)
PAPER_REJOIN = 0.5


# ----------------------------------------------------------------- small types
@dataclass
class StepStart:
    """Controller state at the start of a step: reference state r and step constants p;
    ``problem`` says why the step cannot be controlled (empty when it can)."""
    r: np.ndarray
    p: np.ndarray
    problem: str = ""


@dataclass
class ControlOutput:
    """One evaluation of a control law at a state."""
    u: np.ndarray          # torques (nu)
    y: np.ndarray          # outputs (nu)
    dy: np.ndarray         # output rates (nu)
    denominator: float     # zero where the controller is singular


class _Controller(abc.ABC):
    """Shared numeric wrappers around ``law`` (built by the subclasses)."""

    name = "controller"
    n_ref = 0
    n_par = 0

    @abc.abstractmethod
    def step_start(self, q, dq) -> StepStart:
        """The per-step parameters fixed at the start of a step (just after an impact)."""

    @abc.abstractmethod
    def describe(self) -> dict:
        """What defines the controller, as a JSON-ready dict."""

    @property
    def gait(self):
        """The reference the controller tracks (alias of ``reference``)."""
        return self.reference

    def evaluate(self, q, dq, tau, r, p) -> ControlOutput:
        """The control law at one state (numeric), with an explicit reference state.

        Parameters
        ----------
        q, dq : array_like
            Configuration (nq,), rad, and velocity, rad/s.
        tau : float
            Time since the start of the step, s.
        r : array_like
            Reference state (``n_ref`` numbers; the time-varying controller's
            (q_u^d, dq_u^d), none for virtual constraints).
        p : array_like
            Step constants (``n_par`` numbers) from :meth:`step_start`.

        Returns
        -------
        ControlOutput
            Torques ``u`` (N m), outputs ``y`` and rates ``dy``, and the decoupling
            ``denominator`` (zero where the controller is singular).
        """
        nq = self.model.nq
        q = as_vector(q, nq, "q")
        dq = as_vector(dq, nq, "dq")
        tau = as_number(tau, "tau")
        r = as_vector(r, self.n_ref, "r")
        p = as_vector(p, self.n_par, "p")
        u, y, dy, den, _, _ = (np.array(v).ravel() for v in self.law(q, dq, tau, r, p))
        return ControlOutput(u=u, y=y, dy=dy, denominator=float(den[0]))


# ===================================================== time-varying controller
class TimeVaryingController(_Controller):
    """Time-varying output control of paper §III with the stride-to-stride correction.

    Implements eqs. (6), (7), (17): the outputs y = v - v^d(tau) that the control
    zeroes, with tau the time since the last impact (the caller restarts it at 0 at
    every impact, as the simulator does, and calls :meth:`step_start`, which restarts
    the reference state), corrected to y_c of eq. (17) (SPEC §3):

    Outputs:  y_c = M q - v^d(tau) - v_c(tau),  M = [M1, I],
    v^d = M q^d(tau), v_c the correction of eq. (18) from y_i = v - v^d and
    dy_i = dv - dv^d just after each impact, rejoining the reference at
    tau = ``rejoin`` T (the paper: T/2).  Torque, eq. (12) with the output acceleration
    of eq. (13) applied to y_c (:mod:`biped_casadi.output_law`); singular where
    D11 - D12 M1 = 0 (eq. 24), which :meth:`singularity` checks along the reference.

    Parameters
    ----------
    model : BipedModel
        The robot.
    reference : Reference
        The reference step (a :class:`gait_opt.Gait`), made for ``model``.
    M1 : array_like, optional
        One number per actuated joint (default zeros: the outputs are q_a).
    gains : Gains, optional
        Output PD of eq. (13) (default ``Gains()``).
    rejoin : float
        Rejoin time of v_c as a fraction of T, in (0, SECTION] (default 1/2, the paper's).

    Notes
    -----
    ``law(q, dq, tau, r, p)``: r = the reference state, p = (y_i, dy_i).
    """

    name = "tv"

    def __init__(self, model, reference, M1=None, gains: Gains | None = None,
                 rejoin: float = PAPER_REJOIN):
        require_same_robot(model, reference)
        self.model, self.reference = model, reference
        nu = model.nu
        self.M1 = check_M1(np.zeros(nu) if M1 is None else M1, nu)
        self.gains = gains if gains is not None else Gains()
        if not isinstance(self.gains, Gains):
            raise ValueError(f"gains must be a Gains, got {type(self.gains).__name__}")
        self.rejoin = as_number(rejoin, "rejoin", positive=True)
        if self.rejoin > SECTION:
            raise ValueError(f"rejoin must be in (0, {SECTION}] (v_c must vanish before the "
                             f"Poincare section at {SECTION} T), got {rejoin!r}")
        self.T = reference.T
        self.t_c = self.rejoin * self.T
        self.M = output_matrix(self.M1)
        self.n_ref = reference.n_state
        self.n_par = 2 * nu
        self._build()

    @property
    def cache_key(self):
        """What the compiled law depends on."""
        return ("tv", self.reference.cache_key, tuple(self.M1), self.gains, self.rejoin)

    def _build(self):
        m, nq, nu = self.model, self.model.nq, self.model.nu
        ref = self.reference.symbolic()
        M1 = ca.DM(self.M1)
        q, dq = ca.SX.sym("q", nq), ca.SX.sym("dq", nq)
        tau = ca.SX.sym("tau")
        r = ca.SX.sym("r", self.n_ref)
        p = ca.SX.sym("p", self.n_par)
        yi, dyi = p[:nu], p[nu:]
        qd, dqd, ddqd, dr = ref(tau, r)
        vc, dvc, ddvc = correction(tau, yi, dyi, self.t_c)
        y = outputs(M1, q) - outputs(M1, qd) - vc                              # eq. (17)
        dy = outputs(M1, dq) - outputs(M1, dqd) - dvc
        ddv = output_acceleration(outputs(M1, ddqd) + ddvc, y, dy, self.gains)  # eq. (13)
        D, H = m.D(q), m.H(q, dq)
        den = decoupling_denominator(D[0, 0], D[0, 1:], M1)                     # eq. (24)
        ddqu = unactuated_acceleration(D, H, M1, ddv)                           # eq. (23)
        u = actuated_torque(D, H, M1, ddqu, ddv)                                # eq. (12)
        self.law = ca.Function("tv_law", [q, dq, tau, r, p], [u, y, dy, den, dr, ca.DM(1)],
                               ["q", "dq", "tau", "r", "p"],
                               ["u", "y", "dy", "den", "dr", "in_range"])
        q0, dq0, _ = self.reference.evaluate(0.0)
        self._vd0 = outputs(self.M1, q0)
        self._dvd0 = outputs(self.M1, dq0)
        self._r0 = np.array(self.reference.r0, dtype=float)

    def step_start(self, q, dq) -> StepStart:
        """The step constants y_i = v - v^d(0), dy_i = dv - dv^d(0) of eq. (17).

        Parameters
        ----------
        q, dq : array_like
            The state at the start of the step (just after an impact), rad and rad/s.

        Returns
        -------
        StepStart
            ``r`` the reference state at tau = 0, ``p`` = (y_i, dy_i).
        """
        nq = self.model.nq
        q = as_vector(q, nq, "q")
        dq = as_vector(dq, nq, "dq")
        yi = outputs(self.M1, q) - self._vd0
        dyi = outputs(self.M1, dq) - self._dvd0
        return StepStart(r=self._r0.copy(), p=np.r_[yi, dyi])

    def torque(self, q, dq, tau, y_i=None, dy_i=None) -> ControlOutput:
        """The control law at (q, dq, tau), the reference state read from the reference.

        Parameters
        ----------
        q, dq : array_like
            Configuration (nq,), rad, and velocity, rad/s.
        tau : float
            Time since the start of the step, s, within the reference's range
            [0, ``reference.t_max``].
        y_i, dy_i : array_like, optional
            The correction's initial output error and rate (nu each; default zero: no
            correction).

        Returns
        -------
        ControlOutput
            Torques, outputs y_c and rates, decoupling denominator.
        """
        nu = self.model.nu
        yi = np.zeros(nu) if y_i is None else as_vector(y_i, nu, "y_i")
        dyi = np.zeros(nu) if dy_i is None else as_vector(dy_i, nu, "dy_i")
        tau = as_number(tau, "tau")
        if not 0 <= tau <= self.reference.t_max:
            raise ValueError(f"tau must lie in [0, {self.reference.t_max:.6g}], got {tau!r}")
        return self.evaluate(q, dq, tau, self.reference.state(tau), np.r_[yi, dyi])

    def singularity(self, n: int = 1001) -> SingularityReport:
        """Whether D11 - D12 M1 vanishes or changes sign along the reference (eq. 23-24).

        Parameters
        ----------
        n : int
            Samples on [0, T].

        Returns
        -------
        SingularityReport
        """
        t = np.linspace(0.0, self.T, n)
        nq = self.model.nq
        D = np.array(self.model.D.map(n)(self.reference.q(t))).reshape(nq, nq, n, order="F")
        return singularity_report(decoupling_denominator(D[0, 0], D[0, 1:], self.M1))

    def describe(self) -> dict:
        """What defines the controller, as a JSON-ready dict.

        Returns
        -------
        dict
            ``controller`` ('tv'), ``M1``, ``gains``, ``rejoin``.
        """
        return dict(controller="tv", M1=self.M1.tolist(), gains=self.gains.to_dict(),
                    rejoin=self.rejoin)


# ================================================= virtual constraints (HZD)
@dataclass
class VirtualConstraints:
    """Virtual constraints H0 q = h_d(theta), theta = c q, fitted to a reference gait.

    h_d is a piecewise quintic Bezier polynomial in theta (a degree-5 B-spline with
    knots of multiplicity 5): on each segment [theta_j, theta_j+1] its six Bezier
    coefficients are fixed by the values and first two theta-derivatives of
    H0 q^d(t) at the ends, taken exactly from the gait at knots theta_j = c q^d(t_j)
    (t_j uniform).  So h_d is C^2, interpolates the orbit with its first two
    derivatives at every knot, and reproduces the whole orbit to ``fit_residual``.
    The knots cover the step [theta^+, theta^-] = [c q^d(0), c q^d(T)] and margins on
    both sides (the reference continued past T and integrated backwards before 0).

    Impact invariance (hybrid zero dynamics, Westervelt, Grizzle et al.): the gait is
    periodic through the impact, and h_d matches values and slopes at theta^- and
    theta^+ exactly, so Delta(S cap Z) lies in Z: a state on the constraint surface at
    the impact lands on it again (``invariance_residual`` measures it).

    Build them with :func:`fit_virtual_constraints`.

    Parameters
    ----------
    c : numpy.ndarray
        Phase variable theta = c q, (nq,).
    H0 : numpy.ndarray
        Output matrix, (nq - 1, nq); [H0; c] is invertible.
    knots : numpy.ndarray
        theta_j, increasing, rad.
    bezier : numpy.ndarray
        Bezier coefficients per segment, (n_segments, 6, nq - 1).
    theta_plus, theta_minus : float
        theta at the start of the reference step and at its end (the impact), rad.
    fit_residual : float
        max ``|H0 q^d - h_d(c q^d)|`` at the segment midpoints, rad.
    invariance_residual : float
        Largest ``|y|``, ``|dy|`` right after the impact of the orbit.
    direction : int
        +1 if theta increases along the step, -1 otherwise.
    h : casadi.Function
        theta -> (h_d, dh_d/dtheta, d2h_d/dtheta2).
    """
    c: np.ndarray
    H0: np.ndarray
    knots: np.ndarray
    bezier: np.ndarray
    theta_plus: float
    theta_minus: float
    fit_residual: float
    invariance_residual: float
    direction: int
    h: ca.Function = field(repr=False)

    @property
    def cache_key(self):
        """Content digest of the constraints (phase, outputs and every coefficient)."""
        h = hashlib.sha256()
        for a in (self.c, self.H0, self.knots, self.bezier):
            h.update(np.ascontiguousarray(a, dtype=float).tobytes())
        return h.hexdigest()

    @property
    def theta_range(self) -> tuple:
        """(first knot, last knot): the phase range where h_d is defined, rad."""
        return float(self.knots[0]), float(self.knots[-1])

    @property
    def P(self) -> np.ndarray:
        """[H0; c]: (outputs, phase) = P q on the constraint surface."""
        return np.vstack([self.H0, self.c])

    def to_dict(self) -> dict:
        """A JSON-ready summary (without the Bezier coefficients).

        Returns
        -------
        dict
            ``c``, ``H0``, ``n_segments``, ``theta_plus``, ``theta_minus``,
            ``theta_range``, ``direction``, ``fit_residual``, ``invariance_residual``.
        """
        return dict(c=self.c.tolist(), H0=self.H0.tolist(), n_segments=len(self.bezier),
                    theta_plus=self.theta_plus, theta_minus=self.theta_minus,
                    theta_range=list(self.theta_range), direction=self.direction,
                    fit_residual=self.fit_residual,
                    invariance_residual=self.invariance_residual)


def _reference_samples(reference, dt: float, t_back: float, t_fwd: float):
    """Times t_j = j dt from about -t_back to t_fwd (within the reference's range) and
    q^d, dq^d, ddq^d there."""
    j_lo = -int(math.floor(min(t_back, -reference.t_min) / dt + 1e-9))
    j_hi = int(math.floor(min(t_fwd, reference.t_max) / dt + 1e-9))
    t = np.arange(j_lo, j_hi + 1) * dt
    q, dq, ddq = reference.evaluate(t)
    return t, q, dq, ddq


def _bezier_spline(H0, q, dq, ddq, th, dth, ddth):
    """h_d(theta) as a degree-5 B-spline with knots of multiplicity 5 at the samples
    theta_j (increasing): on each segment the six Bezier coefficients match the values
    and first two theta-derivatives of H0 q at both ends.  Returns (Function
    theta -> (h, dh, ddh), Bezier coefficients (n_segments, 6, nu))."""
    Y = H0 @ q
    dY = H0 @ dq / dth
    ddY = (H0 @ ddq - dY * ddth) / dth**2
    w = np.diff(th)
    y0, y1 = Y[:, :-1], Y[:, 1:]
    d0, d1 = dY[:, :-1] * w, dY[:, 1:] * w
    e0, e1 = ddY[:, :-1] * w**2, ddY[:, 1:] * w**2
    B = np.stack([y0, y0 + d0 / 5, y0 + 2 * d0 / 5 + e0 / 20,
                  y1 - 2 * d1 / 5 + e1 / 20, y1 - d1 / 5, y1], axis=0)   # 6 x nu x nseg
    bez = np.transpose(B, (2, 0, 1))                                      # nseg x 6 x nu
    coef = np.vstack([bez[0]] + [b[1:] for b in bez[1:]])               # (5 nseg + 1) x nu
    knots = [th[0]] * 6 + [x for x in th[1:-1] for _ in range(5)] + [th[-1]] * 6
    spline = ca.Function.bspline("h_d_bspline", [knots], coef.ravel().tolist(), [5], H0.shape[0], {})
    x = ca.MX.sym("theta")
    hx = spline(x)
    dh = ca.jacobian(hx, x)
    ddh = ca.jacobian(dh, x)
    hfun = ca.Function("h_d", [x], [hx, dh, ddh], ["theta"], ["h", "dh", "ddh"],
                       {"never_inline": True})
    return hfun, bez


def fit_virtual_constraints(gait, c=None, H0=None, segments_per_step: int = 200,
                            margin_before: float = 0.25, margin_after: float = 0.25
                            ) -> VirtualConstraints:
    """Fit impact-invariant virtual constraints H0 q = h_d(c q) to a reference.

    Parameters
    ----------
    gait : Reference
        The reference step (a :class:`gait_opt.Gait`).
    c : array_like, optional
        Phase variable theta = c q, strictly monotonic along the reference (checked);
        default the model's ``hip_phase`` (the stance-foot-to-hip angle; for RABBIT
        :data:`HIP_PHASE`).
    H0 : array_like, optional
        (nq - 1) x nq output matrix (default [0, I]: q_a = h_d(theta)); [H0; c] must be
        invertible.
    segments_per_step : int
        Bezier segments per reference step (knots every T / this).
    margin_before, margin_after : float
        Extra range of theta before the step and after its end, in units of T, so that
        perturbed states stay inside the fitted range.

    Returns
    -------
    VirtualConstraints
        With the fit and impact-invariance residuals.

    Raises
    ------
    ValueError
        When c q is not strictly monotonic along the step, [H0; c] is singular, or an
        argument is out of range.
    """
    nq = gait.model.nq
    c = as_vector(gait.model.hip_phase if c is None else c, nq, "c")
    H0 = np.hstack([np.zeros((nq - 1, 1)), np.eye(nq - 1)]) if H0 is None \
        else np.asarray(H0, dtype=float)
    if H0.shape != (nq - 1, nq) or not np.all(np.isfinite(H0)):
        raise ValueError(f"H0 must be a finite {nq - 1} x {nq} matrix, got shape {H0.shape}")
    P = np.vstack([H0, c])
    if np.linalg.cond(P) > 1e10:
        raise ValueError("[H0; c] must be invertible (outputs and phase variable determine q)")
    if isinstance(segments_per_step, bool) or not isinstance(segments_per_step, int) \
            or segments_per_step < 4:
        raise ValueError(f"segments_per_step must be an integer >= 4, got {segments_per_step!r}")
    for name, v in (("margin_before", margin_before), ("margin_after", margin_after)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and 0 <= v <= 1):
            raise ValueError(f"{name} must be in [0, 1], got {v!r}")
    T = gait.T
    t, q, dq, ddq = _reference_samples(gait, T / segments_per_step, margin_before * T,
                                       (1 + margin_after) * T)
    th = c @ q
    dth = c @ dq
    ddth = c @ ddq
    inside = (t >= -1e-12) & (t <= T + 1e-12)
    sign = np.sign(dth[inside].mean())
    if not np.all(sign * dth[inside] > 0):
        raise ValueError("c: the phase variable c q is not strictly monotonic along the "
                         "reference step")
    # keep the largest monotonic stretch around the step
    mono = sign * dth > 0
    i0 = int(np.argmax(inside))
    i1 = len(t) - 1 - int(np.argmax(inside[::-1]))
    lo, hi = i0, i1
    while lo > 0 and mono[lo - 1]:
        lo -= 1
    while hi < len(t) - 1 and mono[hi + 1]:
        hi += 1
    sl = slice(lo, hi + 1)
    t, q, dq, ddq, th, dth, ddth = t[sl], q[:, sl], dq[:, sl], ddq[:, sl], th[sl], dth[sl], ddth[sl]
    if sign < 0:                       # knots must increase
        t, q, dq, ddq, th, dth, ddth = (a[..., ::-1] for a in (t, q, dq, ddq, th, dth, ddth))
    hfun, bez = _bezier_spline(H0, q, dq, ddq, th, dth, ddth)
    # fit residual at segment midpoints (times between knots, from the gait itself)
    tm = 0.5 * (t[:-1] + t[1:])
    tm = tm[(tm >= 0) & (tm <= gait.t_max)]
    qm = gait.q(tm)
    hm = np.array(hfun.map(len(tm))((c @ qm)[None, :])[0])
    fit = float(np.max(np.abs(H0 @ qm - hm)))
    vcs = VirtualConstraints(c=c, H0=H0, knots=np.asarray(th), bezier=bez,
                             theta_plus=float(c @ gait.q(0.0)), theta_minus=float(c @ gait.q(T)),
                             fit_residual=fit, invariance_residual=math.nan,
                             direction=int(sign), h=hfun)
    # impact invariance: outputs right after the orbit's impact
    qp, dqp = (np.array(v).ravel() for v in gait.model.impact(gait.q(T), gait.dq(T)))
    h0, dh0, _ = (np.array(v).ravel() for v in hfun(c @ qp))
    vcs.invariance_residual = float(max(np.max(np.abs(H0 @ qp - h0)),
                                        np.max(np.abs(H0 @ dqp - dh0 * (c @ dqp)))))
    return vcs


class VirtualConstraintController(_Controller):
    """Virtual-constraint (HZD) controller, for the comparison of paper §V-C.

    Outputs y = H0 q - h_d(theta), theta = c q, with h_d fitted to the same reference
    gait (:func:`fit_virtual_constraints`).  Input-output linearisation with the same output dynamics as eq. (13),
    ddy = -Kd/eps dy - Kp/eps^2 y: with J = H0 - h'(theta) c,
    ddy = J ddq - h''(theta) (c dq)^2, and the unactuated row of eq. (1),

        [D_1; J] ddq = [-H_1; -Kd/eps dy - Kp/eps^2 y + h'' (c dq)^2],
        u = rows 2..n of (D ddq + H).

    With ``correction`` (default) the constraints of each step are h = h_d + h_c with
    the stride-to-stride correction of eq. (18) written in the phase instead of time:
    h_c(theta) = v_c(s, y_i, dy_i/ds, S) with s = theta - theta_i (theta_i at the start
    of the step, s counted along the walking direction) and S = ``|theta^- - theta^+|``, so
    h_c carries the output error and its rate at the start of the step and vanishes
    from the middle of the step on.  On the hybrid zero dynamics y_i = dy_i = 0 (the
    constraints are impact invariant): the correction only changes how states off the
    constraint surface join it, not the restricted Poincaré map
    (:mod:`analysis.virtual_constraints`).  Without it the PD of the outputs alone
    brings the state to the surface.

    ``den`` = det [D_1; J] / det [c; H0]: zero where the controller is singular.
    ``in_range`` = 0 once theta leaves the fitted range.  No reference state; the step
    constants are p = (theta_i, y_i, dy_i/ds) with the correction, none without.

    Parameters
    ----------
    model : BipedModel
        The robot.
    gait : Reference
        The reference step the constraints are fitted to, made for ``model``.
    constraints : VirtualConstraints, optional
        Default: :func:`fit_virtual_constraints` of ``gait`` with its defaults.
    gains : Gains, optional
        Output PD of eq. (13) (default ``Gains()``).
    correction : bool
        Add the phase-based stride-to-stride correction h_c (default True).
    """

    name = "vc"
    n_ref = 0

    def __init__(self, model, gait, constraints: VirtualConstraints | None = None,
                 gains: Gains | None = None, correction: bool = True):
        require_same_robot(model, gait)
        self.model, self.reference = model, gait
        self.constraints = constraints if constraints is not None else fit_virtual_constraints(gait)
        if not isinstance(self.constraints, VirtualConstraints):
            raise ValueError("constraints must be a VirtualConstraints "
                             "(see fit_virtual_constraints)")
        self.gains = gains if gains is not None else Gains()
        if not isinstance(self.gains, Gains):
            raise ValueError(f"gains must be a Gains, got {type(self.gains).__name__}")
        if not isinstance(correction, bool):
            raise ValueError(f"correction must be True or False, got {correction!r}")
        self.correction = correction
        self.n_par = 1 + 2 * model.nu if correction else 0
        self.T = gait.T
        self._build()

    @property
    def cache_key(self):
        """What the compiled law depends on."""
        return ("vc", self.reference.cache_key, self.constraints.cache_key, self.gains,
                self.correction)

    def _build(self):
        m, k, vc = self.model, self.gains, self.constraints
        nq, nu = m.nq, m.nu
        q, dq = ca.SX.sym("q", nq), ca.SX.sym("dq", nq)
        tau = ca.SX.sym("tau")
        r = ca.SX.sym("r", 0)
        p = ca.SX.sym("p", self.n_par)
        c = ca.DM(vc.c).T
        H0 = ca.DM(vc.H0)
        th = ca.mtimes(c, q)
        dth = ca.mtimes(c, dq)
        h, dh, ddh = vc.h(th)
        if self.correction:
            sgn = float(vc.direction)
            span = abs(vc.theta_minus - vc.theta_plus)
            hc, dhc, ddhc = correction(sgn * (th - p[0]), p[1:1 + nu], p[1 + nu:], span / 2)
            h, dh, ddh = h + hc, dh + sgn * dhc, ddh + ddhc
        y = ca.mtimes(H0, q) - h
        J = H0 - ca.mtimes(dh, c)
        dy = ca.mtimes(J, dq)
        D = m.D(q)
        H = m.H(q, dq)
        A = ca.vertcat(D[0, :], J)
        rhs = ca.vertcat(-H[0], output_acceleration(ddh * dth**2, y, dy, k))
        ddq = ca.solve(A, rhs)
        u = (ca.mtimes(D, ddq) + H)[1:]
        den = ca.det(A) / float(np.linalg.det(vc.P))
        lo, hi = vc.theta_range
        in_range = ca.logic_and(th >= lo, th <= hi)
        self.law = ca.Function("vc_law", [q, dq, tau, r, p], [u, y, dy, den, ca.SX(0, 1), in_range],
                               ["q", "dq", "tau", "r", "p"],
                               ["u", "y", "dy", "den", "dr", "in_range"])
        self.phase = ca.Function("phase", [q], [th], ["q"], ["theta"])
        qs, dqs = ca.SX.sym("q", nq), ca.SX.sym("dq", nq)
        th0 = ca.mtimes(c, qs)
        h0, dh0, _ = vc.h(th0)
        J0 = H0 - ca.mtimes(dh0, c)
        self._uncorrected = ca.Function("vc_uncorrected_outputs", [qs, dqs],
                                        [th0, ca.mtimes(c, dqs), ca.mtimes(H0, qs) - h0,
                                         ca.mtimes(J0, dqs)],
                                        ["q", "dq"], ["theta", "dtheta", "y", "dy"])

    def step_start(self, q, dq) -> StepStart:
        """The step constants of the phase-based correction at the start of a step.

        theta_i = c q, y_i = H0 q - h_d(theta_i) and dy_i/ds = (J dq) / (dtheta along
        the walking direction); nothing without ``correction``.

        Parameters
        ----------
        q, dq : array_like
            The state at the start of the step (just after an impact), rad and rad/s.

        Returns
        -------
        StepStart
            ``p`` = (theta_i, y_i, dy_i/ds) (empty without correction); ``problem``
            says why the step cannot start (the phase moving backwards).
        """
        nq = self.model.nq
        q = as_vector(q, nq, "q")
        dq = as_vector(dq, nq, "dq")
        if not self.correction:
            return StepStart(r=np.zeros(0), p=np.zeros(0))
        th, dth, y, dy = (np.array(v).ravel() for v in self._uncorrected(q, dq))
        ds = float(dth[0]) * self.constraints.direction
        if not ds > 0:
            return StepStart(r=np.zeros(0), p=np.full(self.n_par, np.nan),
                             problem=f"the phase variable moves backwards at the start of the "
                                     f"step (dtheta = {float(dth[0]):.4g} rad/s)")
        return StepStart(r=np.zeros(0), p=np.r_[th, y, dy / ds])

    def torque(self, q, dq) -> ControlOutput:
        """The control law at (q, dq) without correction (y_i = dy_i = 0).

        Parameters
        ----------
        q, dq : array_like
            Configuration (nq,), rad, and velocity, rad/s.

        Returns
        -------
        ControlOutput
            Torques, outputs and rates, decoupling denominator.
        """
        p = np.zeros(self.n_par)
        if self.correction:
            p[0] = float(self.constraints.c @ as_vector(q, self.model.nq, "q"))
        return self.evaluate(q, dq, 0.0, np.zeros(0), p)

    def singularity(self, n: int = 1001) -> SingularityReport:
        """Whether det [D_1; J] / det [c; H0] vanishes or changes sign along the step.

        Parameters
        ----------
        n : int
            Samples on [0, T].

        Returns
        -------
        SingularityReport
        """
        t = np.linspace(0.0, self.T, n)
        q, dq = self.reference.q(t), self.reference.dq(t)
        p = np.zeros((self.n_par, n))
        if self.correction:
            p[0] = self.constraints.c @ q
        out = self.law.map(n)(q, dq, np.zeros((1, n)), np.zeros((0, n)), p)
        return singularity_report(np.array(out[3]).ravel())

    def describe(self) -> dict:
        """What defines the controller, as a JSON-ready dict.

        Returns
        -------
        dict
            ``controller`` ('vc'), ``gains``, ``correction`` and the constraints'
            :meth:`VirtualConstraints.to_dict`.
        """
        return dict(controller="vc", gains=self.gains.to_dict(), correction=self.correction,
                    **self.constraints.to_dict())
