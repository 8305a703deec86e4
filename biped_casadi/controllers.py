"""Closed-loop controllers for walking: the time-varying output controller of the paper
(§III, eq. 12-13, 17) and, for the comparison of §V-C, a virtual-constraint (hybrid zero
dynamics) controller fitted to the same reference gait.

Both controllers are CasADi Functions built once per controller object and share one
interface used by :mod:`biped_casadi.simulate`:

``law(q, dq, tau, r, p) -> (u, y, dy, den, dr, in_range)``
    torques u (4), outputs y and their rates dy (4), the decoupling denominator ``den``
    (zero where the controller is singular), the time derivative ``dr`` of the
    controller's reference state r, and ``in_range`` (1 while the reference is defined
    at the current state).
``step_start(q, dq) -> StepStart(r, p)``
    the reference state r and the per-step constants p at the start of a step (just
    after an impact, or at the initial state).

Reference state r.  The time-varying controller needs q_u^d(tau), which the gait
defines as the solution of the unactuated row of eq. (1) with q_a = q_a^d(tau) (SPEC
§2).  ``r = (q_u^d, dq_u^d)`` is that ODE, integrated alongside the robot and reset to
the gait's x0 at every tau = 0: it is a function of tau alone, so the hybrid closed loop
is still the 11-dimensional system in (q, dq, tau) of eq. (9).  Past T it continues
exactly as the gait's own continuation (the Bezier q_a^d evaluated past s = 1 and the
same ODE for q_u^d), i.e. the reference is smooth (C-infinity) across T.
"""
from __future__ import annotations

import abc

import math
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from .correction import v_correction

__all__ = ["Gains", "StepStart", "ControlOutput", "SingularityReport",
           "TimeVaryingController", "VirtualConstraints", "VirtualConstraintController",
           "fit_virtual_constraints", "HIP_PHASE"]

#: phase variable c of the virtual-constraint controller, theta = c q: the angle of the
#: line stance foot -> hip from the vertical, exactly q1 + q2 / 2 when tibia and femur
#: are equally long (RABBIT), a linear stand-in for it otherwise.
HIP_PHASE = (1.0, 0.5, 0.0, 0.0, 0.0)


# ----------------------------------------------------------------- small types
@dataclass(frozen=True)
class Gains:
    """PD gains of the output dynamics, ddy = -Kd/eps dy - Kp/eps^2 y (eq. 13).

    eps small = high gain: the closed loop approaches its zero dynamics."""
    Kp: float = 1.0
    Kd: float = 2.0
    eps: float = 0.02

    def __post_init__(self):
        for name in ("Kp", "Kd", "eps"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise ValueError(f"gain {name!r} must be a positive finite number, got {v!r}")

    def to_dict(self) -> dict:
        return dict(Kp=self.Kp, Kd=self.Kd, eps=self.eps)


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
    u: np.ndarray          # torques (4)
    y: np.ndarray          # outputs (4)
    dy: np.ndarray         # output rates (4)
    denominator: float     # zero where the controller is singular


@dataclass
class SingularityReport:
    """The decoupling denominator along the reference step (eq. 23-24 for the
    time-varying controller)."""
    min_abs: float
    min_value: float
    max_value: float
    changes_sign: bool

    @property
    def singular(self) -> bool:
        return self.changes_sign or self.min_abs < 1e-9 * max(abs(self.min_value),
                                                              abs(self.max_value))

    def to_dict(self) -> dict:
        return dict(min_abs=self.min_abs, min_value=self.min_value, max_value=self.max_value,
                    changes_sign=self.changes_sign, singular=self.singular)


# ----------------------------------------------------------------- helpers
def _vector(x, n, name):
    a = np.asarray(x, dtype=float)
    if a.shape != (n,):
        raise ValueError(f"{name} must have {n} components, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite, got {a.tolist()}")
    return a


def _check_gait(model, gait):
    if gait.model.params != model.params:
        raise ValueError("gait was made for other robot parameters than the model")


def _reference_dynamics(gait):
    from gait_opt.reference import reference_dynamics
    return reference_dynamics(gait.model, gait.options.bezier_degree)


def _denominator_report(values) -> SingularityReport:
    d = np.asarray(values, dtype=float)
    return SingularityReport(min_abs=float(np.min(np.abs(d))), min_value=float(d.min()),
                             max_value=float(d.max()),
                             changes_sign=bool(d.min() * d.max() <= 0))


class _Controller(abc.ABC):
    """Shared numeric wrappers around ``law`` (built by the subclasses)."""

    name = "controller"
    n_ref = 0
    n_par = 0

    @abc.abstractmethod
    def step_start(self, q, dq) -> StepStart:
        """The per-step parameters fixed at the start of a step (just after an impact)."""

    def evaluate(self, q, dq, tau, r, p) -> ControlOutput:
        """The control law at one state (numeric), with an explicit reference state."""
        q = _vector(q, 5, "q")
        dq = _vector(dq, 5, "dq")
        if not (isinstance(tau, (int, float, np.floating)) and math.isfinite(tau)):
            raise ValueError(f"tau must be a finite number, got {tau!r}")
        r = _vector(r, self.n_ref, "r")
        p = _vector(p, self.n_par, "p")
        u, y, dy, den, _, _ = (np.array(v).ravel() for v in self.law(q, dq, tau, r, p))
        return ControlOutput(u=u, y=y, dy=dy, denominator=float(den[0]))


# ===================================================== time-varying controller
class TimeVaryingController(_Controller):
    """Time-varying output control of paper §III-A with the stride-to-stride correction
    of §III-C (SPEC §3).

    Outputs, eq. (17):  y_c = M q - v^d(tau) - v_c(tau),  M = [M1, I_4],
    v^d = M q^d(tau), v_c the correction of eq. (18) (:func:`v_correction`) from
    y_i = v - v^d and dy_i = dv - dv^d just after each impact.
    Torque, eq. (12) with the output acceleration of eq. (13) applied to y_c:

        ddv = ddv^d + ddv_c - Kd/eps dy_c - Kp/eps^2 y_c
        ddq_u = (-D12 ddv - H1) / (D11 - D12 M1)                        (eq. 23)
        u = (D21 - D22 M1) ddq_u + D22 ddv + H2                          (eq. 12)

    singular where D11 - D12 M1 = 0 (eq. 24); :meth:`singularity` checks the reference.
    ``law(q, dq, tau, r, p)``: r = (q_u^d, dq_u^d) (module docstring), p = (y_i, dy_i).
    """

    name = "tv"
    n_ref = 2
    n_par = 8

    def __init__(self, model, gait, M1=(0.0, 0.0, 0.0, 0.0), gains: Gains | None = None):
        _check_gait(model, gait)
        self.model, self.gait = model, gait
        self.M1 = _vector(M1, 4, "M1")
        self.gains = gains if gains is not None else Gains()
        if not isinstance(self.gains, Gains):
            raise ValueError(f"gains must be a Gains, got {type(self.gains).__name__}")
        self.T = gait.T
        self.M = np.hstack([self.M1[:, None], np.eye(4)])
        self._build()

    def _build(self):
        m, g, T, k = self.model, self.gait, self.T, self.gains
        ref = _reference_dynamics(g)
        alpha = ca.DM(g.alpha)
        M1 = ca.DM(self.M1)
        Mm = ca.DM(self.M)
        q = ca.SX.sym("q", 5)
        dq = ca.SX.sym("dq", 5)
        tau = ca.SX.sym("tau")
        r = ca.SX.sym("r", 2)
        p = ca.SX.sym("p", 8)
        yi, dyi = p[:4], p[4:]
        qa_d, dqa_d, ddqa_d = ref.qa(alpha, tau / T, T)
        qd = ca.vertcat(r[0], qa_d)
        dqd = ca.vertcat(r[1], dqa_d)
        ddqu_d = ref.ddqu(qd, dqd, ddqa_d)
        ddqd = ca.vertcat(ddqu_d, ddqa_d)
        vc, dvc, ddvc = v_correction(tau, yi, dyi, T)
        y = ca.mtimes(Mm, q) - ca.mtimes(Mm, qd) - vc
        dy = ca.mtimes(Mm, dq) - ca.mtimes(Mm, dqd) - dvc
        ddv = ca.mtimes(Mm, ddqd) + ddvc - k.Kd / k.eps * dy - k.Kp / k.eps**2 * y
        D = m.D(q)
        H = m.H(q, dq)
        D11, D12 = D[0, 0], D[0, 1:]
        den = D11 - ca.mtimes(D12, M1)
        ddqu = (-ca.mtimes(D12, ddv) - H[0]) / den
        u = ca.mtimes(D[1:, 0] - ca.mtimes(D[1:, 1:], M1), ddqu) + ca.mtimes(D[1:, 1:], ddv) + H[1:]
        dr = ca.vertcat(r[1], ddqu_d)
        self.law = ca.Function("tv_law", [q, dq, tau, r, p], [u, y, dy, den, dr, ca.DM(1)],
                               ["q", "dq", "tau", "r", "p"],
                               ["u", "y", "dy", "den", "dr", "in_range"])
        xd0 = np.asarray(g.x0, dtype=float)
        qa0, dqa0, _ = (np.array(v).ravel() for v in ref.qa(alpha, 0.0, T))
        self._vd0 = self.M @ np.r_[xd0[0], qa0]
        self._dvd0 = self.M @ np.r_[xd0[1], dqa0]
        self._r0 = xd0

    def step_start(self, q, dq) -> StepStart:
        """y_i = v - v^d(0), dy_i = dv - dv^d(0) at the start of a step (eq. 17)."""
        q = _vector(q, 5, "q")
        dq = _vector(dq, 5, "dq")
        yi = self.M @ q - self._vd0
        dyi = self.M @ dq - self._dvd0
        return StepStart(r=self._r0.copy(), p=np.r_[yi, dyi])

    def torque(self, q, dq, tau, y_i=None, dy_i=None) -> ControlOutput:
        """The law at (q, dq, tau) with the reference q_u^d(tau) taken from the gait
        (0 <= tau <= 2T) and corrections y_i, dy_i (default zero)."""
        yi = np.zeros(4) if y_i is None else _vector(y_i, 4, "y_i")
        dyi = np.zeros(4) if dy_i is None else _vector(dy_i, 4, "dy_i")
        if not (isinstance(tau, (int, float, np.floating)) and math.isfinite(tau)):
            raise ValueError(f"tau must be a finite number, got {tau!r}")
        if not 0 <= tau <= self.gait.t_max:
            raise ValueError(f"tau must lie in [0, {self.gait.t_max:.6g}], got {tau!r}")
        return self.evaluate(q, dq, float(tau), self.gait.state_at(tau), np.r_[yi, dyi])

    def singularity(self, n: int = 1001) -> SingularityReport:
        """D11 - D12 M1 along the reference step on [0, T] (eq. 23-24)."""
        t = np.linspace(0.0, self.T, n)
        D = np.array(self.model.D.map(n)(self.gait.q(t))).reshape(5, 5, n, order="F")
        return _denominator_report(D[0, 0] - self.M1 @ D[0, 1:])

    def describe(self) -> dict:
        return dict(controller="tv", M1=self.M1.tolist(), gains=self.gains.to_dict())


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
    """
    c: np.ndarray                  # phase variable theta = c q (5)
    H0: np.ndarray                 # output matrix (4 x 5); [H0; c] invertible
    knots: np.ndarray              # theta_j, increasing
    bezier: np.ndarray             # (n_segments, 6, 4) Bezier coefficients per segment
    theta_plus: float              # theta at the start of the reference step
    theta_minus: float             # theta at its end (impact)
    fit_residual: float            # max |H0 q^d - h_d(c q^d)| at segment midpoints
    invariance_residual: float     # |y|, |dy| right after the impact of the orbit
    direction: int                 # +1 if theta increases along the step, -1 otherwise
    h: ca.Function = field(repr=False)   # theta -> (h, dh/dtheta, d2h/dtheta2)

    @property
    def theta_range(self) -> tuple:
        return float(self.knots[0]), float(self.knots[-1])

    @property
    def P(self) -> np.ndarray:
        """[H0; c]: (outputs, phase) = P q on the constraint surface."""
        return np.vstack([self.H0, self.c])

    def to_dict(self) -> dict:
        return dict(c=self.c.tolist(), H0=self.H0.tolist(), n_segments=len(self.bezier),
                    theta_plus=self.theta_plus, theta_minus=self.theta_minus,
                    theta_range=list(self.theta_range), direction=self.direction,
                    fit_residual=self.fit_residual,
                    invariance_residual=self.invariance_residual)


def _reference_samples(gait, t_back: float, t_fwd: float, stride: int):
    """q^d, dq^d, ddq^d at t = k T / n (n = the gait's polish grid) for k from
    -t_back n / T to t_fwd n / T in steps of ``stride``; before 0 the unactuated row is
    integrated backwards from x0 with the same RK4 as the gait."""
    ref = _reference_dynamics(gait)
    n = gait.options.polish_steps
    T = gait.T
    k_back = int(round(t_back * n / T)) // stride * stride
    k_fwd = int(round(t_fwd * n / T)) // stride * stride
    k_fwd = min(k_fwd, int(math.floor(gait.t_max * n / T + 1e-9)) // stride * stride)
    ks_fwd = np.arange(0, k_fwd + 1, stride)
    t_f = ks_fwd * T / n
    q_f, dq_f, ddq_f = gait.q(t_f), gait.dq(t_f), gait.ddq(t_f)
    if k_back == 0:
        return t_f, q_f, dq_f, ddq_f
    X = np.array(ref.integrate(k_back)(gait.x0, 0.0, -1.0 / n, gait.alpha, T))
    ks_b = np.arange(stride, k_back + 1, stride)           # k = -stride, -2 stride, ...
    xb = X[:, ks_b - 1]
    s_b = -ks_b / n
    qa, dqa, ddqa = (np.array(v) for v in ref.qa.map(len(s_b))(gait.alpha, s_b[None, :], T))
    q_b = np.vstack([xb[0], qa])
    dq_b = np.vstack([xb[1], dqa])
    ddqu = np.array(ref.ddqu.map(len(s_b))(q_b, dq_b, ddqa))
    ddq_b = np.vstack([ddqu, ddqa])
    order = np.argsort(s_b)
    return (np.r_[(s_b * T)[order], t_f], np.hstack([q_b[:, order], q_f]),
            np.hstack([dq_b[:, order], dq_f]), np.hstack([ddq_b[:, order], ddq_f]))


def fit_virtual_constraints(gait, c=HIP_PHASE, H0=None, segments_per_step: int = 200,
                            margin_before: float = 0.25, margin_after: float = 0.25
                            ) -> VirtualConstraints:
    """Fit impact-invariant virtual constraints H0 q = h_d(c q) to ``gait``.

    c: phase variable theta = c q, strictly monotonic along the reference (checked);
    H0: 4 x 5 output matrix (default [0, I_4]: q_a = h_d(theta)) with [H0; c] invertible;
    segments_per_step: Bezier segments per reference step (knots every T / this);
    margin_before / margin_after: extra range of theta before the step and after its
    end, in units of T, so that perturbed states stay inside the fitted range.
    """
    c = _vector(c, 5, "c")
    H0 = np.hstack([np.zeros((4, 1)), np.eye(4)]) if H0 is None else np.asarray(H0, dtype=float)
    if H0.shape != (4, 5) or not np.all(np.isfinite(H0)):
        raise ValueError(f"H0 must be a finite 4 x 5 matrix, got shape {H0.shape}")
    P = np.vstack([H0, c])
    if np.linalg.cond(P) > 1e10:
        raise ValueError("[H0; c] must be invertible (outputs and phase variable determine q)")
    if not isinstance(segments_per_step, int) or segments_per_step < 4:
        raise ValueError(f"segments_per_step must be an integer >= 4, got {segments_per_step!r}")
    n = gait.options.polish_steps
    if n % segments_per_step:
        raise ValueError(f"segments_per_step must divide the gait's polish_steps ({n}), "
                         f"got {segments_per_step}")
    for name, v in (("margin_before", margin_before), ("margin_after", margin_after)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and 0 <= v <= 1):
            raise ValueError(f"{name} must be in [0, 1], got {v!r}")
    T = gait.T
    stride = n // segments_per_step
    t, q, dq, ddq = _reference_samples(gait, margin_before * T, (1 + margin_after) * T, stride)
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
    Y = H0 @ q
    dY = H0 @ dq / dth
    ddY = (H0 @ ddq - dY * ddth) / dth**2
    w = np.diff(th)
    y0, y1 = Y[:, :-1], Y[:, 1:]
    d0, d1 = dY[:, :-1] * w, dY[:, 1:] * w
    e0, e1 = ddY[:, :-1] * w**2, ddY[:, 1:] * w**2
    B = np.stack([y0, y0 + d0 / 5, y0 + 2 * d0 / 5 + e0 / 20,
                  y1 - 2 * d1 / 5 + e1 / 20, y1 - d1 / 5, y1], axis=0)   # 6 x 4 x nseg
    bez = np.transpose(B, (2, 0, 1))                                      # nseg x 6 x 4
    coef = np.vstack([bez[0]] + [b[1:] for b in bez[1:]])               # (5 nseg + 1) x 4
    knots = [th[0]] * 6 + [x for x in th[1:-1] for _ in range(5)] + [th[-1]] * 6
    spline = ca.Function.bspline("h_d_bspline", [knots], coef.ravel().tolist(), [5], 4, {})
    x = ca.MX.sym("theta")
    hx = spline(x)
    dh = ca.jacobian(hx, x)
    ddh = ca.jacobian(dh, x)
    hfun = ca.Function("h_d", [x], [hx, dh, ddh], ["theta"], ["h", "dh", "ddh"],
                       {"never_inline": True})
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
    """Virtual-constraint (HZD) controller: outputs y = H0 q - h_d(theta), theta = c q,
    with h_d fitted to the same reference gait (:func:`fit_virtual_constraints`).

    Input-output linearisation with the same output dynamics as eq. (13),
    ddy = -Kd/eps dy - Kp/eps^2 y: with J = H0 - h'(theta) c,
    ddy = J ddq - h''(theta) (c dq)^2, and the unactuated row of eq. (1),

        [D_1; J] ddq = [-H_1; -Kd/eps dy - Kp/eps^2 y + h'' (c dq)^2],
        u = rows 2..5 of (D ddq + H).

    With ``correction`` (default) the constraints of each step are h = h_d + h_c with
    the stride-to-stride correction of eq. (18) written in the phase instead of time:
    h_c(theta) = v_c(s, y_i, dy_i/ds, S) with s = theta - theta_i (theta_i at the start
    of the step, s counted along the walking direction) and S = |theta^- - theta^+|, so
    h_c carries the output error and its rate at the start of the step and vanishes
    from the middle of the step on.  On the hybrid zero dynamics y_i = dy_i = 0 (the
    constraints are impact invariant): the correction only changes how states off the
    constraint surface join it, not the restricted Poincaré map
    (:mod:`analysis.virtual_constraints`).  Without it the PD of the outputs alone
    brings the state to the surface.

    ``den`` = det [D_1; J] / det [c; H0]: zero where the controller is singular.
    ``in_range`` = 0 once theta leaves the fitted range.  No reference state; the step
    constants are p = (theta_i, y_i, dy_i/ds) with the correction, none without.
    """

    name = "vc"
    n_ref = 0

    def __init__(self, model, gait, constraints: VirtualConstraints | None = None,
                 gains: Gains | None = None, correction: bool = True):
        _check_gait(model, gait)
        self.model, self.gait = model, gait
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
        self.n_par = 9 if correction else 0
        self.T = gait.T
        self._build()

    def _build(self):
        m, k, vc = self.model, self.gains, self.constraints
        q = ca.SX.sym("q", 5)
        dq = ca.SX.sym("dq", 5)
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
            hc, dhc, ddhc = v_correction(sgn * (th - p[0]), p[1:5], p[5:9], span)
            h, dh, ddh = h + hc, dh + sgn * dhc, ddh + ddhc
        y = ca.mtimes(H0, q) - h
        J = H0 - ca.mtimes(dh, c)
        dy = ca.mtimes(J, dq)
        D = m.D(q)
        H = m.H(q, dq)
        A = ca.vertcat(D[0, :], J)
        rhs = ca.vertcat(-H[0], -k.Kd / k.eps * dy - k.Kp / k.eps**2 * y + ddh * dth**2)
        ddq = ca.solve(A, rhs)
        u = (ca.mtimes(D, ddq) + H)[1:]
        den = ca.det(A) / float(np.linalg.det(vc.P))
        lo, hi = vc.theta_range
        in_range = ca.logic_and(th >= lo, th <= hi)
        self.law = ca.Function("vc_law", [q, dq, tau, r, p], [u, y, dy, den, ca.SX(0, 1), in_range],
                               ["q", "dq", "tau", "r", "p"],
                               ["u", "y", "dy", "den", "dr", "in_range"])
        self.phase = ca.Function("phase", [q], [th], ["q"], ["theta"])
        qs, dqs = ca.SX.sym("q", 5), ca.SX.sym("dq", 5)
        th0 = ca.mtimes(c, qs)
        h0, dh0, _ = vc.h(th0)
        J0 = H0 - ca.mtimes(dh0, c)
        self._uncorrected = ca.Function("vc_uncorrected_outputs", [qs, dqs],
                                        [th0, ca.mtimes(c, dqs), ca.mtimes(H0, qs) - h0,
                                         ca.mtimes(J0, dqs)],
                                        ["q", "dq"], ["theta", "dtheta", "y", "dy"])

    def step_start(self, q, dq) -> StepStart:
        """theta_i, y_i = H0 q - h_d(theta_i) and dy_i/ds = (J dq) / (dtheta along the
        walking direction) at the start of a step (correction only)."""
        q = _vector(q, 5, "q")
        dq = _vector(dq, 5, "dq")
        if not self.correction:
            return StepStart(r=np.zeros(0), p=np.zeros(0))
        th, dth, y, dy = (np.array(v).ravel() for v in self._uncorrected(q, dq))
        ds = float(dth[0]) * self.constraints.direction
        if not ds > 0:
            return StepStart(r=np.zeros(0), p=np.full(9, np.nan),
                             problem=f"the phase variable moves backwards at the start of the "
                                     f"step (dtheta = {float(dth[0]):.4g} rad/s)")
        return StepStart(r=np.zeros(0), p=np.r_[th, y, dy / ds])

    def torque(self, q, dq) -> ControlOutput:
        """The law at (q, dq) (numeric), without correction (y_i = dy_i = 0)."""
        p = np.zeros(self.n_par)
        if self.correction:
            p[0] = float(self.constraints.c @ np.asarray(q, dtype=float))
        return self.evaluate(q, dq, 0.0, np.zeros(0), p)

    def singularity(self, n: int = 1001) -> SingularityReport:
        """det [D_1; J] / det [c; H0] along the reference step on [0, T]."""
        t = np.linspace(0.0, self.T, n)
        q, dq = self.gait.q(t), self.gait.dq(t)
        p = np.zeros((self.n_par, n))
        if self.correction:
            p[0] = self.constraints.c @ q
        out = self.law.map(n)(q, dq, np.zeros((1, n)), np.zeros((0, n)), p)
        return _denominator_report(np.array(out[3]).ravel())

    def describe(self) -> dict:
        return dict(controller="vc", gains=self.gains.to_dict(), correction=self.correction,
                    **self.constraints.to_dict())

