"""Published virtual constraints as a gait: the periodic orbit of their hybrid zero
dynamics, sampled as nodes.

The constraints are given as in the HZD literature (Westervelt, Grizzle et al.):
outputs y = H0 q - h_d(s) with h_d a Bezier polynomial of degree M in the normalised
phase s = (theta - theta^+) / (theta^- - theta^+), theta = c q linear in q.  On the
constraint surface q = Q(theta) = [H0; c]^-1 [h_d(s(theta)); theta], and the unactuated
row of eq. (1) (docs/theory.md) gives the zero dynamics

    D_1(Q) (Q' ddtheta + Q'' dtheta^2) + H_1(Q, Q' dtheta) = 0,

integrated in theta (RK4 on w = dtheta, dw/dtheta = ddtheta / w, and t, dt/dtheta =
1 / w) from theta^+ to theta^-.  The impact (eq. 2-3) then gives w^+ = c dq^+; the
periodic orbit is the fixed point w^+ = w (Newton, derivative by AD).  Its samples
(t, Q, Q' w, Q' ddtheta + Q'' w^2) are what :func:`gait_opt.import_gait` fits.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from math import comb

import casadi as ca
import numpy as np

from biped_casadi.control.reference import require_reference
from biped_casadi.numerics import as_vector, rk4_step

from .nodes import Nodes

__all__ = ["BezierConstraints", "constraints_from_dict", "hzd_nodes", "fit_bezier_constraints"]


@dataclass(frozen=True)
class BezierConstraints:
    """Virtual constraints H0 q = h_d(s), s = (c q - theta^+) / (theta^- - theta^+).

    Parameters
    ----------
    alpha : numpy.ndarray
        (nu, M + 1) Bezier coefficients of h_d, rad.
    theta_plus, theta_minus : float
        The phase just after and just before the impact, rad.
    phase : numpy.ndarray
        c of theta = c q, (nq,).
    H0 : numpy.ndarray or None
        (nu, nq) outputs (default [0, I]: the actuated joints q_2..q_n).
    """

    alpha: np.ndarray
    theta_plus: float
    theta_minus: float
    phase: np.ndarray
    H0: np.ndarray | None = None

    def to_dict(self) -> dict:
        """The record of a ``virtual_constraints`` file (:func:`constraints_from_dict`).

        Returns
        -------
        dict
            ``bezier`` (nu lists), ``theta_plus``, ``theta_minus``, ``phase`` and
            ``outputs`` (H0) when given.
        """
        d = dict(bezier=np.asarray(self.alpha).tolist(), theta_plus=float(self.theta_plus),
                 theta_minus=float(self.theta_minus), phase=np.asarray(self.phase).tolist())
        if self.H0 is not None:
            d["outputs"] = np.asarray(self.H0).tolist()
        return d


def constraints_from_dict(d, nq: int, where: str = "virtual constraints") -> BezierConstraints:
    """Validated constraints from a record ``bezier``, ``theta_plus``, ``theta_minus``,
    ``phase`` (and optionally ``outputs``).

    Parameters
    ----------
    d : dict
        The record.
    nq : int
        The robot's number of coordinates.
    where : str
        Names the source in messages.

    Returns
    -------
    BezierConstraints

    Raises
    ------
    ValueError
        Naming ``where`` and the key.
    """
    if not isinstance(d, dict):
        raise ValueError(f"{where}: must be an object with bezier, theta_plus, theta_minus, "
                         f"phase")
    missing = [k for k in ("bezier", "theta_plus", "theta_minus", "phase") if k not in d]
    if missing:
        raise ValueError(f"{where}: missing key(s) {', '.join(missing)}")
    unknown = sorted(set(d) - {"bezier", "theta_plus", "theta_minus", "phase", "outputs"})
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {', '.join(unknown)}")
    try:
        alpha = np.array(d["bezier"], dtype=float)
        c = np.array(d["phase"], dtype=float).ravel()
        tp, tm = float(d["theta_plus"]), float(d["theta_minus"])
        H0 = None if d.get("outputs") is None else np.array(d["outputs"], dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: bezier, phase, theta_plus, theta_minus (and outputs) "
                         f"must be numbers") from None
    nu = nq - 1
    if alpha.ndim != 2 or alpha.shape[0] != nu or alpha.shape[1] < 4:
        raise ValueError(f"{where}: bezier must be {nu} rows of at least 4 coefficients "
                         f"(one row per output), got shape {alpha.shape}")
    if c.shape != (nq,):
        raise ValueError(f"{where}: phase must have {nq} numbers (theta = phase . q)")
    if H0 is not None and H0.shape != (nu, nq):
        raise ValueError(f"{where}: outputs must be a {nu} x {nq} matrix")
    for name, a in (("bezier", alpha), ("phase", c), ("theta", np.r_[tp, tm])) + (
            (("outputs", H0),) if H0 is not None else ()):
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{where}: {name} has a NaN or infinite value")
    if not abs(tm - tp) > 1e-9:
        raise ValueError(f"{where}: theta_plus and theta_minus must differ")
    P = np.vstack([np.hstack([np.zeros((nu, 1)), np.eye(nu)]) if H0 is None else H0, c])
    if np.linalg.cond(P) > 1e10:
        raise ValueError(f"{where}: [outputs; phase] must be invertible")
    return BezierConstraints(alpha, tp, tm, c, H0)


def _curve(model, vc: BezierConstraints):
    """theta -> (Q, Q', Q'') and the zero-dynamics acceleration (theta, w) -> ddtheta."""
    nu = model.nu
    M = vc.alpha.shape[1] - 1
    H0 = np.hstack([np.zeros((nu, 1)), np.eye(nu)]) if vc.H0 is None else vc.H0
    Pinv = np.linalg.inv(np.vstack([H0, vc.phase]))
    th = ca.SX.sym("theta")
    s = (th - vc.theta_plus) / (vc.theta_minus - vc.theta_plus)
    h = sum(ca.DM(vc.alpha[:, k]) * comb(M, k) * s**k * (1 - s)**(M - k) for k in range(M + 1))
    Q = ca.mtimes(ca.DM(Pinv), ca.vertcat(h, th))
    Q1 = ca.jacobian(Q, th)
    Q2 = ca.jacobian(Q1, th)
    w = ca.SX.sym("w")
    D1 = model.D(Q)[0, :]
    H1 = model.H(Q, Q1 * w)[0]
    acc = -(ca.mtimes(D1, Q2) * w**2 + H1) / ca.mtimes(D1, Q1)
    curve = ca.Function("vc_curve", [th], [Q, Q1, Q2], ["theta"], ["Q", "dQ", "ddQ"])
    accel = ca.Function("vc_zero_dynamics", [th, w], [acc], ["theta", "w"], ["ddtheta"])
    return curve, accel


def _one_step(model, vc, curve, accel, n: int):
    """w^+ -> (w after the impact, the (w, t) samples) as a Function of w^+."""
    tp, tm = vc.theta_plus, vc.theta_minus
    h = (tm - tp) / n
    x = ca.SX.sym("x", 2)                          # (w, t)
    th = ca.SX.sym("th")
    f = lambda xx, c: ca.vertcat(accel(th + c * h, xx[0]) / xx[0], 1 / xx[0])  # noqa: E731
    step = ca.Function("step", [x, th], [rk4_step(f, x, h), th + h])
    acc = step.mapaccum("hzd_steps", n, [0, 1], [0, 1])
    w0 = ca.MX.sym("w0")
    X, _ = acc(ca.vertcat(w0, 0), tp)
    wm = X[0, -1]
    qm, Q1m, _ = curve(tm)
    _, dqp = model.impact(qm, Q1m * wm)
    wp = ca.mtimes(ca.DM(vc.phase).T, dqp)
    return ca.Function("hzd_step", [w0], [wp, ca.jacobian(wp, w0), X], ["w0"],
                       ["w_plus", "dw_plus", "X"])


def hzd_nodes(model, vc: BezierConstraints, n: int = 400) -> tuple:
    """The periodic orbit of the constraints' hybrid zero dynamics, as nodes.

    Parameters
    ----------
    model : BipedModel
        The robot.
    vc : BezierConstraints
        The constraints.
    n : int
        RK4 steps in theta over the step (n + 1 nodes).

    Returns
    -------
    tuple
        (:class:`Nodes`, info dict: ``w_plus`` (rad/s), ``fixed_point_residual``,
        ``invariance_residual`` (how far the impact of the orbit lands from the
        constraint surface: max over ``|q^+ - Q(theta^+)|``, ``|dq^+ - Q' w^+|``),
        ``delta_zero_squared`` (the angular momentum about the stance foot after /
        before the impact, squared)).

    Raises
    ------
    ValueError
        When the zero dynamics has no periodic orbit that crosses the whole step
        (no speed at which the phase reaches theta^-).
    """
    curve, accel = _curve(model, vc)
    step = _one_step(model, vc, curve, accel, n)
    sign = 1.0 if vc.theta_minus > vc.theta_plus else -1.0

    def crossed(w):
        """(w^+, dw^+/dw, samples) when the phase crosses the whole step, else None."""
        wp, dwp, X = (np.array(v) for v in step(w))
        ok = np.all(np.isfinite(X)) and np.all(X[0] * sign > 0) and np.isfinite(wp).all()
        return (wp.item(), dwp.item(), X) if ok else None

    grid = [(sign * v, crossed(sign * v)) for v in np.geomspace(0.05, 20, 60)]
    grid = [(w, r[0] - w) for w, r in grid if r is not None]
    pairs = [(a, b) for a, b in zip(grid, grid[1:]) if a[1] * b[1] <= 0]
    if not pairs:
        raise ValueError("virtual constraints: the zero dynamics has no periodic orbit "
                         "(no speed from 0.05 to 20 rad/s returns to itself after the "
                         "impact, or the phase never reaches theta_minus)")
    (lo, _), (hi, _) = pairs[-1]
    w = 0.5 * (lo + hi)
    for _ in range(60):                      # Newton kept inside the bracket [lo, hi]
        wp, dwp, _ = crossed(w)
        g = wp - w
        if (g > 0) == ((crossed(lo)[0] - lo) > 0):
            lo = w
        else:
            hi = w
        new = w - g / (dwp - 1.0) if dwp != 1.0 else math.nan
        if not (min(lo, hi) < new < max(lo, hi)) or crossed(new) is None:
            new = 0.5 * (lo + hi)
        done = abs(new - w) <= 1e-14 * max(1.0, abs(w))
        w = new
        if done:
            break
    wp, _, X = crossed(w)
    if not abs(wp - w) <= 1e-9 * max(1.0, abs(w)):
        raise ValueError(f"virtual constraints: the zero dynamics has no periodic orbit "
                         f"(|w+ - w| = {abs(wp - w):.2e} rad/s after Newton)")
    ths = vc.theta_plus + (vc.theta_minus - vc.theta_plus) * np.arange(n + 1) / n
    ws = np.r_[w, X[0]]
    t = np.r_[0.0, X[1]]
    Q, Q1, Q2 = (np.array(v) for v in curve.map(n + 1)(ths[None, :]))
    dd = np.array(accel.map(n + 1)(ths[None, :], ws[None, :])).ravel()
    nodes = Nodes(t, Q, Q1 * ws, Q1 * dd + Q2 * ws**2, "virtual constraints")
    qp, dqp = (np.array(v).ravel() for v in model.impact(Q[:, -1], Q1[:, -1] * ws[-1]))
    inv = max(float(np.max(np.abs(qp - Q[:, 0]))), float(np.max(np.abs(dqp - Q1[:, 0] * w))))
    sig_m = float(np.array(model.D(Q[:, -1]))[0] @ (Q1[:, -1] * ws[-1]))
    sig_p = float(np.array(model.D(qp))[0] @ dqp)
    info = dict(w_plus=w, fixed_point_residual=abs(wp - w), invariance_residual=inv,
                delta_zero_squared=(sig_p / sig_m) ** 2 if sig_m else math.nan)
    return nodes, info


def fit_bezier_constraints(gait, degree: int = 10, phase=None, n: int = 2001) -> BezierConstraints:
    """Impact-invariant Bezier virtual constraints q_a = h_d(s) of a periodic gait.

    The form in which virtual constraints are published: h_d over s = (theta -
    theta^+) / (theta^- - theta^+), theta = c q.  The two first and two last coefficients
    match the gait's q_a and dq_a/ds at the impact exactly (so the constraints are
    impact invariant when the gait is periodic); the others are a least-squares fit on
    ``n`` times of [0, T].

    Parameters
    ----------
    gait : Gait
        A periodic gait.
    degree : int
        M >= 4.
    phase : array_like, optional
        c (default the model's ``hip_phase``); c q^d must be strictly monotonic.
    n : int
        Samples of the fit.

    Returns
    -------
    BezierConstraints
        With ``H0`` None (the outputs are q_a).
    """
    m = require_reference(gait).model
    c = as_vector(m.hip_phase if phase is None else phase, m.nq, "phase")
    if isinstance(degree, bool) or not isinstance(degree, int) or degree < 4:
        raise ValueError(f"degree must be an integer >= 4, got {degree!r}")
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < degree + 1:
        raise ValueError(f"n (samples of the fit) must be an integer >= degree + 1 = "
                         f"{degree + 1}, got {n!r}")
    t = np.linspace(0, gait.T, n)
    q, dq, _ = gait.evaluate(t)
    th = c @ q
    if not np.all(np.diff(th) * np.sign(th[-1] - th[0]) > 0):
        raise ValueError("phase: c q is not strictly monotonic along the gait")
    span = th[-1] - th[0]
    s = (th - th[0]) / span
    M = degree
    B = np.array([[comb(M, k) * si**k * (1 - si)**(M - k) for k in range(M + 1)] for si in s])
    ds = (c @ dq) / span
    qa, slope = q[1:], dq[1:] / ds                       # dq_a/ds
    alpha = np.zeros((m.nu, M + 1))
    alpha[:, 0], alpha[:, M] = qa[:, 0], qa[:, -1]
    alpha[:, 1] = qa[:, 0] + slope[:, 0] / M
    alpha[:, M - 1] = qa[:, -1] - slope[:, -1] / M
    fixed = [0, 1, M - 1, M]
    free = [k for k in range(M + 1) if k not in fixed]
    rhs = qa.T - B[:, fixed] @ alpha[:, fixed].T
    alpha[:, free] = np.linalg.lstsq(B[:, free], rhs, rcond=None)[0].T
    return BezierConstraints(alpha, float(th[0]), float(th[-1]), c)
