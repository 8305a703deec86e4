"""Polish: the exact periodic orbit through the impact.

Collocation satisfies the unactuated row of eq. (1) at the nodes only.  The exported
reference takes q_u^d as the ODE solution from (q_u(0), dq_u(0)) (fine RK4), and a
minimum-norm Newton iteration on all parameters (alpha, x0, T), with the exact Jacobian
by forward sensitivities of every RK4 step (AD), restores periodicity through the impact,
z_sw(T) = 0 and the speed to ~1e-12 (at round-off, 1e-11 .. 1e-9, on an ill-conditioned
robot such as a light shin under a heavy torso).  The corrections are of the size of the
collocation error (4e-11 in the parameters at the default transcription, whose q_u
polynomial is within 7e-8 rad of the exact solution between the nodes; see
benchmarks/bench_gait.py), far below the inequality margins.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from biped_casadi.caching import cached
from biped_casadi.results import Result

from .errors import GaitOptimizationError
from .gait import ORBIT_TOL, Gait
from .parametrisation import reference_dynamics

__all__ = ["polish", "close_orbit", "ClosedOrbit"]


@cached(maxsize=16)
def _polish_function(model, bezier_degree: int, n_steps: int):
    """(p = (vec alpha, x0, T)) -> (x(1), dx(1)/dp): n RK4 steps of the unactuated row
    with forward sensitivities propagated step by step (exact Jacobian of the discrete
    integrator, by AD of one step)."""
    ref = reference_dynamics(model, bezier_degree)
    nu = model.nu
    na = nu * (bezier_degree + 1)
    x = ca.SX.sym("x", 2)
    S = ca.SX.sym("S", 2, na + 3)
    s = ca.SX.sym("s")
    ds = ca.SX.sym("ds")
    a = ca.SX.sym("alpha", nu, bezier_degree + 1)
    T = ca.SX.sym("T")
    xn, sn = ref.rk4(x, s, ds, a, T)
    J = ca.jacobian(xn, ca.vertcat(ca.vec(a), x, T))
    Sn = ca.mtimes(J[:, na:na + 2], S) + ca.horzcat(J[:, :na], ca.SX.zeros(2, 2), J[:, na + 2])
    step = ca.Function("rk4_sens", [x, S, s, ds, a, T], [xn, Sn, sn])
    acc = step.mapaccum("rk4_sens_acc", n_steps, [0, 1, 2], [0, 1, 2])
    p = ca.MX.sym("p", na + 3)
    am = ca.reshape(p[:na], nu, bezier_degree + 1)
    S0 = ca.horzcat(ca.MX.zeros(2, na), ca.MX.eye(2), ca.MX.zeros(2, 1))
    X, SS, _ = acc(p[na:na + 2], S0, 0, 1.0 / n_steps, am, p[na + 2])
    with_sens = ca.Function("unactuated_flow_sens", [p], [X[:, -1], SS[:, -(na + 3):]],
                            ["p"], ["x1", "dx1_dp"])
    X = ref.integrate(n_steps)(p[na:na + 2], 0, 1.0 / n_steps, am, p[na + 2])
    plain = ca.Function("unactuated_flow", [p], [X[:, -1]], ["p"], ["x1"])
    return plain, with_sens


@cached(maxsize=16)
def _periodicity_residual(model, bezier_degree: int):
    """(p, x(1), speed) -> residual (impact+relabel - start (2 nq), z_sw(T), x_sw(T) - v T)
    and its Jacobians in p and x(1)."""
    ref = reference_dynamics(model, bezier_degree)
    nu = model.nu
    na = nu * (bezier_degree + 1)
    p = ca.SX.sym("p", na + 3)
    x1 = ca.SX.sym("x1", 2)
    v = ca.SX.sym("v")
    a = ca.reshape(p[:na], nu, bezier_degree + 1)
    xs0, Tm = p[na:na + 2], p[na + 2]
    qa0, dqa0, _ = ref.qa(a, 0, Tm)
    qa1, dqa1, _ = ref.qa(a, 1, Tm)
    qm = ca.vertcat(x1[0], qa1)
    dqm = ca.vertcat(x1[1], dqa1)
    qp, dqp = model.impact(qm, dqm)
    xe, ze = model.swing_foot(qm)
    r = ca.vertcat(qp - ca.vertcat(xs0[0], qa0), dqp - ca.vertcat(xs0[1], dqa0), ze, xe - v * Tm)
    return ca.Function("periodicity_residual", [p, x1, v],
                       [r, ca.jacobian(r, p), ca.jacobian(r, x1)], ["p", "x1", "v"],
                       ["r", "dr_dp", "dr_dx1"])


def polish(model, opts, alpha, x0, T, tol=1e-12, max_iter=20):
    """Minimum-norm Newton on (alpha, x0, T) for the exact periodic orbit (module doc).

    The Jacobian (forward sensitivities through every RK4 step) is refreshed only when
    the residual contracts by less than 10x (chord steps otherwise).  On an
    ill-conditioned robot (a light shin under a heavy torso) the residual can wander at
    round-off above 1e-10 until ``max_iter``: the best iterate is then kept when its
    residual is within :data:`~gait_opt.gait.ORBIT_TOL` (the orbit's bound in the
    definition of a gait), and ``hist`` ends at it."""
    plain, with_sens = _polish_function(model, opts.bezier_degree, opts.polish_steps)
    res = _periodicity_residual(model, opts.bezier_degree)
    na = model.nu * (opts.bezier_degree + 1)
    pv = np.r_[np.asarray(alpha, dtype=float).ravel(order="F"), np.ravel(x0), float(T)]
    hist, Jv, best = [], None, (np.inf, pv, 0)
    for _ in range(max_iter):
        if Jv is None:
            x1, S = (np.array(v) for v in with_sens(pv))
        else:
            x1 = np.array(plain(pv))
        rv, Rp, Rx = (np.array(v) for v in res(pv, x1, opts.speed))
        rv = rv.ravel()
        hist.append(float(np.max(np.abs(rv))))
        if hist[-1] < best[0]:
            best = (hist[-1], pv, len(hist))
        if not np.isfinite(hist[-1]) or hist[-1] <= tol \
                or (len(hist) > 3 and hist[-1] < 1e-10 and hist[-1] >= hist[-2]):
            break      # converged, stagnating at round-off, or diverged
        if Jv is not None and hist[-1] > 0.1 * hist[-2]:     # chord step too slow
            S = np.array(with_sens(pv)[1])
            Jv = None
        if Jv is None:
            Jv = Rp + Rx @ S
        pv = pv - np.linalg.lstsq(Jv, rv, rcond=None)[0]
    if not hist[-1] <= max(tol, 1e-10) and best[0] <= ORBIT_TOL:
        pv, hist = best[1], hist[:best[2]]          # wandering at round-off: the best
    if not hist[-1] <= ORBIT_TOL:
        raise GaitOptimizationError(
            f"polish (Newton on the exact periodic orbit) did not converge: residual "
            f"{hist[-1]:.2e} after {len(hist)} iterations (at most {ORBIT_TOL:g} needed); "
            f"try more collocation intervals (--intervals, n_intervals=) or RK4 steps "
            f"(polish_steps=)", status="polish_failed")
    a_new = pv[:na].reshape(model.nu, -1, order="F")
    return a_new, pv[na:na + 2], float(pv[na + 2]), hist



@dataclass
class ClosedOrbit(Result):
    """A gait made an exact periodic orbit of its robot by :func:`close_orbit`.

    ``success`` means the Newton iteration converged.

    Parameters
    ----------
    gait : Gait
        The closed gait (the input gait when it did not converge).
    status : str
        'closed' or 'not_converged'.
    residual_before, residual_after : float
        The orbit residual of the gait's parametrisation (the periodicity through the
        impact and relabelling, z_sw(T) and the speed, max abs: rad, rad/s, m) before
        and after.
    parameter_change : float
        max ``|p_after - p_before|`` over the Bezier coefficients (rad), x0 (rad, rad/s)
        and T (s).
    T_change : float
        s.
    iterations : int
        Newton iterations.
    history : list of float
        The residual at each iteration.
    message : str
        What happened.
    """

    gait: object = field(repr=False, metadata={"dict": False})
    status: str = "closed"
    residual_before: float = math.nan
    residual_after: float = math.nan
    parameter_change: float = math.nan
    T_change: float = math.nan
    iterations: int = 0
    history: list = field(default_factory=list)
    message: str = ""

    SUCCESS = ("closed",)


def close_orbit(gait, speed: float | None = None, tol: float = 1e-12,
                max_iter: int = 20) -> ClosedOrbit:
    """Make an almost periodic gait an exact periodic orbit of its robot.

    The minimum-norm Newton iteration of :func:`polish` on the gait's own parameters
    (the Bezier coefficients of q_a^d, x0 = (q_u^d(0), dq_u^d(0)) and T) with the exact
    Jacobian (forward sensitivities of every RK4 step of the unactuated row of eq. (1),
    docs/theory.md): periodic through the impact and the relabelling (eq. 2-3), the
    swing foot on the ground at T, and the step length ``speed`` x T.

    Parameters
    ----------
    gait : Gait
        The gait to close (its options give the Bezier degree and the RK4 steps).
    speed : float, optional
        m/s; default the gait's ``options.speed``.
    tol : float
        Residual to reach.
    max_iter : int
        Newton iterations at most.

    Returns
    -------
    ClosedOrbit
        The closed gait (options with ``speed``) and what moved.
    """
    if not isinstance(gait, Gait):
        raise TypeError(f"gait: a Gait is needed (Gait.load(path) or optimize_gait(model)), "
                        f"got {type(gait).__name__}")
    if isinstance(tol, bool) or not isinstance(tol, (int, float)) or not 0 < tol < math.inf:
        raise ValueError(f"tol must be a positive number, got {tol!r}")
    if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or max_iter < 1:
        raise ValueError(f"max_iter must be a positive integer, got {max_iter!r}")
    opts = gait.options if speed is None else gait.options.replace(speed=float(speed))
    p0 = np.r_[gait.alpha.ravel(order="F"), gait.x0, gait.T]
    try:
        alpha, x0, T, hist = polish(gait.model, opts, gait.alpha, gait.x0, gait.T, tol, max_iter)
    except GaitOptimizationError as e:
        return ClosedOrbit(gait, status="not_converged", message=str(e))
    new = Gait(gait.model, opts, alpha, x0, T, solver_stats=dict(gait.solver_stats))
    p1 = np.r_[alpha.ravel(order="F"), x0, T]
    return ClosedOrbit(new, residual_before=hist[0], residual_after=hist[-1],
                       parameter_change=float(np.max(np.abs(p1 - p0))), T_change=T - gait.T,
                       iterations=len(hist) - 1, history=hist,
                       message=f"closed in {len(hist) - 1} Newton iteration(s): residual "
                               f"{hist[0]:.2e} -> {hist[-1]:.2e}")
