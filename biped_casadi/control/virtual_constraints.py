"""Virtual constraints (hybrid zero dynamics) fitted to a reference gait, their controller
for the comparison of paper §V-C, and the constraint surface they define.
"""
from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from ..caching import cached
from ..numerics import as_vector, rk4_step
from .controller import ControlOutput, Controller, StepStart
from .output_law import Gains, SingularityReport, correction, output_acceleration, singularity_report
from .reference import require_reference, require_same_robot

__all__ = ["VirtualConstraints", "VirtualConstraintController", "fit_virtual_constraints",
           "ConstraintSurface", "constraint_surface", "HIP_PHASE", "phase_correction",
           "rejoin_phase"]

#: RABBIT's phase variable c of the virtual-constraint controller, theta = c q: the angle
#: of the line stance foot -> hip from the vertical, exactly q1 + q2 / 2 when tibia and
#: femur are equally long.  Every model has its own (``model.hip_phase``, the default).
HIP_PHASE = (1.0, 0.5, 0.0, 0.0, 0.0)


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


def phase_correction(vc: VirtualConstraints, theta, p, nu: int, t_c=None):
    """The constraints of a step with the phase-based correction: h_d + h_c and two
    theta-derivatives.

    h_c(theta) = v_c(s, y_i, dy_i/ds, S/2) (eq. 18 written in the phase), s = theta -
    theta_i counted along the walking direction, S = ``|theta^- - theta^+|``; the step
    constants are p = (theta_i, y_i, dy_i/ds).  Shared by the controller and the
    corrected constraint surface (:class:`ConstraintSurface`).

    Parameters
    ----------
    vc : VirtualConstraints
        The constraints.
    theta : casadi
        The phase, rad.
    p : casadi
        (1 + 2 nu,) step constants.
    nu : int
        Outputs.
    t_c : float or casadi, optional
        The rejoin phase S/2 (default); a symbol keeps compiled code free of the gait's
        numbers (:class:`~biped_casadi.simulation.vc_walker.VirtualConstraintWalker`).

    Returns
    -------
    tuple
        (h, dh/dtheta, d2h/dtheta2), each (nu,).
    """
    h, dh, ddh = vc.h(theta)
    sgn = float(vc.direction)
    if t_c is None:
        t_c = rejoin_phase(vc)
    hc, dhc, ddhc = correction(sgn * (theta - p[0]), p[1:1 + nu], p[1 + nu:], t_c)
    return h + hc, dh + sgn * dhc, ddh + ddhc


def rejoin_phase(vc: VirtualConstraints) -> float:
    """Where the phase-based correction has died out: S/2 past the step's start, rad.

    Parameters
    ----------
    vc : VirtualConstraints
        The constraints (S = ``|theta^- - theta^+|``).

    Returns
    -------
    float
    """
    return abs(vc.theta_minus - vc.theta_plus) / 2


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
    nq = require_reference(gait).model.nq
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


class VirtualConstraintController(Controller):
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
    (:mod:`analysis.stability.vc_map`).  Without it the PD of the outputs alone
    brings the state to the surface.

    ``den`` = det [D_1; J] / det [c; H0]: zero where the controller is singular.
    ``in_range`` = 0 once theta leaves the fitted range.  No reference state; the step
    constants are p = (theta_i, y_i, dy_i/ds) with the correction, none without
    (``start(q, dq) -> (r, p)``: :meth:`step_start` as a CasADi Function, without its
    check of the phase's direction).

    Parameters
    ----------
    gait : Reference
        The reference step the constraints are fitted to (it carries its model).
    constraints : VirtualConstraints, optional
        Default: :func:`fit_virtual_constraints` of ``gait`` with its defaults.
    gains : Gains, optional
        Output PD of eq. (13) (default ``Gains()``).
    correction : bool
        Add the phase-based stride-to-stride correction h_c (default True).
    """

    name = "vc"
    n_ref = 0

    def __init__(self, gait, constraints: VirtualConstraints | None = None,
                 gains: Gains | None = None, correction: bool = True):
        model = require_reference(gait).model
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
        h, dh, ddh = phase_correction(vc, th, p, nu) if self.correction else vc.h(th)
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
        ds = ca.mtimes(c, dqs) * float(vc.direction)
        p0 = ca.vertcat(th0, ca.mtimes(H0, qs) - h0, ca.mtimes(J0, dqs) / ds) \
            if self.correction else ca.SX(0, 1)
        self.start = ca.Function("vc_step_start", [qs, dqs], [ca.SX(0, 1), p0],
                                 ["q", "dq"], ["r", "p"])

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


class ConstraintSurface:
    """The constraint surface of virtual constraints and the motion on it.

    On Z = {H0 q = h_d(theta)}, theta = c q, the configuration is a function of the phase
    alone, q = Q(theta) = [H0; c]^-1 [h_d(theta); theta], and the zero dynamics is the
    unactuated row of eq. (1) along that curve,

        D_1(Q) (Q' ddtheta + Q'' dtheta^2) + H_1(Q, Q' dtheta) = 0,

    with the phase as the independent variable: the state on Z is w = dtheta/dt and
    dw/dtheta = ddtheta / w.  The swing foot strikes at the fixed phase theta^- where
    z_sw(Q(theta^-)) = 0 (near the reference's impact), whatever the velocity; after the
    impact and relabelling the state lands on Z again at theta^+ = c E Q(theta^-).  The
    restricted Poincaré map (:mod:`analysis.stability.vc_map`) and the batched walker
    (:mod:`biped_casadi.simulation.vc_walker`) are built on these Functions.

    Parameters
    ----------
    model : BipedModel
        The robot.
    constraints : VirtualConstraints
        From :func:`fit_virtual_constraints`.

    Notes
    -----
    CasADi Functions, built once: ``curve(theta) -> (Q, dQ/dtheta, D_1 Q')``,
    ``curve_second(theta) -> d2Q/dtheta2``, ``zero_dynamics(theta, w) -> dw/dtheta``,
    ``foot(theta) -> (x_sw, z_sw, dz_sw/dtheta)``, ``rk4(w, theta, h) -> (w, theta)``
    (one RK4 step of length h in the phase).

    The corrected surface of one step, with the controller's phase-based correction
    h_c (:func:`phase_correction`, step constants p = (theta_i, y_i, dy_i/ds)), is the
    same motion from any state at the start of a step: ``corrected(theta, w, p) ->
    (Q, Q', Q'', dw/dtheta, D_1 Q', d2theta/dt2)``, ``corrected_foot(theta, p) -> (x_sw, z_sw,
    dz_sw/dtheta)``, and ``step_start(q, dq) -> (theta_i, w_i, p)`` (p as the
    controller's ``step_start``).  With y_i = dy_i = 0 it is the surface itself.
    """

    def __init__(self, model, constraints: VirtualConstraints):
        if not isinstance(constraints, VirtualConstraints):
            raise ValueError("constraints must be a VirtualConstraints")
        self.model, self.vc = model, constraints
        self._build_curve()
        self._find_impact()

    @property
    def cache_key(self):
        """What the surface depends on: the model and the constraints."""
        return (self.model.cache_key, self.vc.cache_key)

    def _build_curve(self):
        m, vc = self.model, self.vc
        th = ca.SX.sym("theta")
        w = ca.SX.sym("w")
        Pinv = ca.DM(np.linalg.inv(vc.P))
        h, dh, ddh = vc.h(th)
        Q = ca.mtimes(Pinv, ca.vertcat(h, th))
        Q1 = ca.mtimes(Pinv, ca.vertcat(dh, 1))
        Q2 = ca.mtimes(Pinv, ca.vertcat(ddh, 0))
        D1 = m.D(Q)[0, :]
        H1 = m.H(Q, Q1 * w)[0]
        den = ca.mtimes(D1, Q1)
        ddth = -(ca.mtimes(D1, Q2) * w**2 + H1) / den
        self.curve = ca.Function("hzd_curve", [th], [Q, Q1, den], ["theta"], ["q", "dq_dtheta", "den"])
        self.curve_second = ca.Function("hzd_curve_second", [th], [Q2], ["theta"], ["d2q_dtheta2"])
        self.zero_dynamics = ca.Function("hzd_dw_dtheta", [th, w], [ddth / w], ["theta", "w"], ["dw"])
        xs, zs = m.swing_foot(Q)
        _, dzs = m.swing_foot_velocity(Q, Q1)
        self.foot = ca.Function("hzd_foot", [th], [xs, zs, dzs], ["theta"], ["x_sw", "z_sw", "dz_dtheta"])
        hs = ca.SX.sym("h")
        f = self.zero_dynamics
        w_next = rk4_step(lambda wv, c: f(th + c * hs, wv), w, hs)
        self.rk4 = ca.Function("hzd_rk4", [w, th, hs], [w_next, th + hs],
                               ["w", "theta", "h"], ["w_next", "theta_next"])
        # the corrected surface of a step (the controller's h_c)
        nu = m.nu
        p = ca.SX.sym("p", 1 + 2 * nu)
        out = self.corrected_expressions(th, w, p)
        Qp, Q1p = out[0], out[1]
        self.corrected = ca.Function("hzd_corrected", [th, w, p], list(out),
                                     ["theta", "w", "p"], ["q", "dq_dtheta", "d2q_dtheta2",
                                                           "dw", "den", "ddtheta"])
        xsp, zsp = m.swing_foot(Qp)
        _, dzsp = m.swing_foot_velocity(Qp, Q1p)
        self.corrected_foot = ca.Function("hzd_corrected_foot", [th, p], [xsp, zsp, dzsp],
                                          ["theta", "p"], ["x_sw", "z_sw", "dz_dtheta"])
        q, dq = ca.SX.sym("q", m.nq), ca.SX.sym("dq", m.nq)
        c = ca.DM(vc.c).T
        th0, dth0 = ca.mtimes(c, q), ca.mtimes(c, dq)
        h0, dh0, _ = vc.h(th0)
        H0 = ca.DM(vc.H0)
        y0, dy0 = ca.mtimes(H0, q) - h0, ca.mtimes(H0 - ca.mtimes(dh0, c), dq)
        ds = dth0 * float(vc.direction)
        self.step_start = ca.Function("hzd_step_start", [q, dq],
                                      [th0, dth0, ca.vertcat(th0, y0, dy0 / ds)],
                                      ["q", "dq"], ["theta", "w", "p"])

    def corrected_expressions(self, th, w, p, t_c=None) -> tuple:
        """The outputs of ``corrected`` as expressions in the given symbols.

        Parameters
        ----------
        th, w : casadi.SX
            The phase and its rate.
        p : casadi.SX
            (1 + 2 nu,) step constants.
        t_c : casadi.SX, optional
            The rejoin phase (default the constraints' S/2, a number).

        Returns
        -------
        tuple
            (Q, Q', Q'', dw/dtheta, D_1 Q', d2theta/dt2).
        """
        m, vc = self.model, self.vc
        Pinv = ca.DM(np.linalg.inv(vc.P))
        hp, dhp, ddhp = phase_correction(vc, th, p, m.nu, t_c)
        Qp = ca.mtimes(Pinv, ca.vertcat(hp, th))
        Q1p = ca.mtimes(Pinv, ca.vertcat(dhp, 1))
        Q2p = ca.mtimes(Pinv, ca.vertcat(ddhp, 0))
        D1p = m.D(Qp)[0, :]
        denp = ca.mtimes(D1p, Q1p)
        ddthp = -(ca.mtimes(D1p, Q2p) * w**2 + m.H(Qp, Q1p * w)[0]) / denp
        return Qp, Q1p, Q2p, ddthp / w, denp, ddthp

    def _find_impact(self):
        """theta^- with z_sw(Q(theta^-)) = 0 near the reference's impact (rootfinder)."""
        th = ca.MX.sym("theta")
        _, z, _ = self.foot(th)
        rf = ca.rootfinder("hzd_impact_phase", "newton", ca.Function("z_sw", [th], [z]),
                           {"abstol": 1e-15, "max_iter": 50, "error_on_fail": False})
        #: the phase of the strike on the surface, rad
        self.theta_minus = float(rf(self.vc.theta_minus))
        qm = np.array(self.curve(self.theta_minus)[0]).ravel()
        qp = self.model.E @ qm
        #: the phase just after the impact (the surface is impact invariant), rad
        self.theta_plus = float(self.vc.c @ qp)

    def phase(self, q) -> float:
        """The phase theta = c q of a configuration.

        Parameters
        ----------
        q : array_like
            (nq,) configuration, rad.

        Returns
        -------
        float
            theta, rad.
        """
        return float(self.vc.c @ np.asarray(q, float))


def constraint_surface(gait, phase=None, H0=None) -> ConstraintSurface:
    """The :class:`ConstraintSurface` of virtual constraints fitted to a gait (memoised).

    Parameters
    ----------
    gait : Reference
        The reference the constraints are fitted to (:func:`fit_virtual_constraints`).
    phase : tuple of float, optional
        theta = ``phase`` q (default the model's ``hip_phase``).
    H0 : tuple of tuples, optional
        Outputs H0 q - h_d(theta) (default q_a).

    Returns
    -------
    ConstraintSurface
        The same object for the same robot, gait, phase and outputs (the defaults
        spelled out or not).
    """
    model = require_reference(gait).model
    phase = tuple(np.asarray(model.hip_phase if phase is None else phase, float).ravel())
    H0 = None if H0 is None else tuple(map(tuple, np.asarray(H0, float)))
    return _surface(model, gait, phase, H0)


@cached(maxsize=8)
def _surface(model, gait, phase, H0) -> ConstraintSurface:
    return ConstraintSurface(model, fit_virtual_constraints(gait, c=phase, H0=H0))
