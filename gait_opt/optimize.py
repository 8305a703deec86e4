"""Direct collocation of RABBIT's cyclic walking step (SPEC section 2), then a polish
that makes the unactuated trajectory exact.

Transcription.  The actuated joints are Bezier polynomials of s = t / T (so q_a^d,
dq_a^d, ddq_a^d are exact everywhere and continue past T); only the unactuated row of
eq. (1) is an ODE, x = (q_u, dq_u), and it is transcribed by orthogonal collocation
(Legendre by default: order 2d at interval ends, i.e. 6 for d = 3, with the same number
of variables as Radau; Radau is available for comparison, see benchmarks/).  Path
constraints (torques, contact force, friction cone, swing-foot clearance) are imposed
at every interval boundary and collocation point; knee limits on the Bezier
coefficients, which bounds the polynomial on the whole step (convex hull).

Polish.  Collocation satisfies the dynamics at the nodes only.  The exported reference
takes q_u^d as the ODE solution from (q_u(0), dq_u(0)) (fine RK4) and a minimum-norm
Newton iteration on all parameters (alpha, x0, T), with exact Jacobians by AD through the
integrator, restores periodicity through the impact, z_sw(T) = 0 and the speed to
~1e-12.  The corrections are of the size of the collocation error (~1e-8), far below
the inequality margins, which are re-checked on a dense grid afterwards.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from .options import GaitOptions
from .reference import reference_dynamics

__all__ = ["optimize_gait", "GaitOptimizationError", "initial_guess"]


class GaitOptimizationError(RuntimeError):
    """IPOPT did not find a feasible gait; the message names the status and the
    constraint families that are violated at the last iterate."""


@dataclass
class _Problem:
    nlp: dict
    lift: ca.Function       # (alpha) -> lifted actuated values at every point
    lbx: np.ndarray
    ubx: np.ndarray
    lbg: np.ndarray
    ubg: np.ndarray
    groups: list            # (name, start, stop) in g
    unpack: ca.Function     # w -> T, alpha, Xs, Xc
    cost_scale: float


def _collocation(opts):
    tau = ca.collocation_points(opts.degree, opts.scheme)
    C, Dend, Bq = ca.collocation_coeff(tau)
    return np.array(tau), np.array(C), np.array(Dend).ravel(), np.array(Bq).ravel()


def _build_problem(model, opts: GaitOptions) -> _Problem:
    ref = reference_dynamics(model, opts.bezier_degree)
    M, N, d = opts.bezier_degree, opts.n_intervals, opts.degree
    tau, C, Dend, Bq = _collocation(opts)
    h = 1.0 / N

    # s of every constrained point: interval starts (0..N) then collocation points
    s_start = np.arange(N + 1) * h
    s_coll = (np.arange(N)[:, None] * h + tau[None, :] * h).ravel()
    s_all = np.r_[s_start, s_coll]
    npts = s_all.size

    # Decision variables.  The actuated joints are lifted at every point (value and s-
    # derivatives tied to alpha by linear equalities): the Hessian of the Lagrangian is
    # then block diagonal per point (plus T), which makes exact Hessians cheap.
    T = ca.MX.sym("T")
    alpha = ca.MX.sym("alpha", 4, M + 1)
    Xs = ca.MX.sym("Xs", 2, N + 1)
    Xc = ca.MX.sym("Xc", 2, N * d)
    QA = ca.MX.sym("QA", 12, npts)          # (qa, dqa/ds, d2qa/ds2) at every point
    w = ca.veccat(T, alpha, Xs, Xc, QA)
    X_all = ca.horzcat(Xs, Xc)

    s_sym = ca.SX.sym("s")
    a_sx = ca.SX.sym("alpha", 4, M + 1)
    qa_s, dqa_s, ddqa_s = ref.qa(a_sx, s_sym, 1.0)       # with T = 1: s-derivatives
    basis = ca.Function("basis", [a_sx, s_sym], [ca.vertcat(qa_s, dqa_s, ddqa_s)])
    QA_of_alpha = basis.map(npts)(alpha, ca.DM(s_all).T)

    # point-wise quantities, mapped over all points
    x = ca.SX.sym("x", 2)
    lifted = ca.SX.sym("lifted", 12)
    T_sx = ca.SX.sym("T")
    q = ca.vertcat(x[0], lifted[:4])
    dq = ca.vertcat(x[1], lifted[4:8] / T_sx)
    ddqa = lifted[8:12] / T_sx**2
    ddq = ca.vertcat(ref.ddqu(q, dq, ddqa), ddqa)
    u = ref.torque(q, dq, ddq)
    Fx, Fz = model.ground_reaction_acc(q, dq, ddq)
    _, zsw = model.swing_foot(q)
    point = ca.Function("point", [x, lifted, T_sx],
                        [T_sx * ca.vertcat(x[1], ddq[0]), u, Fx, Fz, zsw])
    pmap = point.map(npts)
    f_all, u_all, Fx_all, Fz_all, z_all = pmap(X_all, QA, T)

    g, lbg, ubg, groups = [], [], [], []

    def add(name, expr, lo, hi):
        expr = ca.vec(expr)
        n = expr.numel()
        start = sum(e.numel() for e in g)
        g.append(expr)
        lbg.append(np.broadcast_to(lo, (n,)).astype(float))
        ubg.append(np.broadcast_to(hi, (n,)).astype(float))
        groups.append((name, start, start + n))

    # collocation equations and continuity
    f_coll = f_all[:, N + 1:]
    coll, cont = [], []
    for k in range(N):
        Z = ca.horzcat(Xs[:, k], Xc[:, k * d:(k + 1) * d])
        coll.append(ca.mtimes(Z, C) - h * f_coll[:, k * d:(k + 1) * d])
        cont.append(ca.mtimes(Z, Dend) - Xs[:, k + 1])
    add("actuated joints (Bezier)", QA - QA_of_alpha, 0, 0)
    add("dynamics (collocation)", ca.horzcat(*coll), 0, 0)
    add("dynamics (continuity)", ca.horzcat(*cont), 0, 0)

    # path constraints
    umax = opts.torque_limit
    add("torque limit", u_all, -umax, umax)
    add("normal force", Fz_all, opts.min_normal_force, np.inf)
    add("friction cone", ca.vertcat(opts.mu * Fz_all - Fx_all, opts.mu * Fz_all + Fx_all), 0, np.inf)
    interior = (s_all > 1e-9) & (s_all < 1 - 1e-9)
    idx = np.flatnonzero(interior)
    clear = opts.clearance * 4 * s_all[idx] * (1 - s_all[idx])
    add("swing-foot clearance", z_all[idx] - ca.DM(clear).T, 0, np.inf)

    # end of step, impact and periodicity
    qa0, dqa0, _ = ref.qa(alpha, 0, T)
    qa1, dqa1, _ = ref.qa(alpha, 1, T)
    q_minus = ca.vertcat(Xs[0, N], qa1)
    dq_minus = ca.vertcat(Xs[1, N], dqa1)
    q_start = ca.vertcat(Xs[0, 0], qa0)
    dq_start = ca.vertcat(Xs[1, 0], dqa0)
    q_plus, dq_plus, F_imp, _, v_old = model.impact_full(q_minus, dq_minus)
    x_end, z_end = model.swing_foot(q_minus)
    _, dz_end = model.swing_foot_velocity(q_minus, dq_minus)
    add("periodicity (q)", q_plus - q_start, 0, 0)
    add("periodicity (dq)", dq_plus - dq_start, 0, 0)
    add("swing foot on ground at T", z_end, 0, 0)
    add("speed", x_end - opts.speed * T, 0, 0)
    add("step length", x_end, opts.step_length_bounds[0], opts.step_length_bounds[1])
    add("strike velocity", dz_end, -np.inf, -opts.min_strike_speed)
    add("lift-off velocity", v_old[1], opts.min_liftoff_speed, np.inf)
    add("impact impulse cone", ca.vertcat(F_imp[1], opts.mu * F_imp[1] - F_imp[0],
                                          opts.mu * F_imp[1] + F_imp[0]), 0, np.inf)

    # cost: integral of u'u dt (Gauss/Radau quadrature), per step length
    u_coll = u_all[:, N + 1:]
    weights = np.tile(Bq, N) * h
    J = T * ca.mtimes(ca.sum1(u_coll**2), ca.DM(weights))
    if opts.cost == "torque_squared_per_length":
        J = J / x_end
    cost_scale = 1e-3
    nlp = {"x": w, "f": cost_scale * J, "g": ca.vertcat(*g)}

    # variable bounds: T, knee limits on the Bezier coefficients, joint angles sane
    nw = w.numel()
    lbx = np.full(nw, -np.inf)
    ubx = np.full(nw, np.inf)
    lbx[0], ubx[0] = opts.step_time_bounds
    a_lb = np.full((4, M + 1), -np.pi)
    a_ub = np.full((4, M + 1), np.pi)
    a_ub[0, :] = opts.stance_knee_max
    a_lb[3, :] = opts.swing_knee_min
    lbx[1:1 + 4 * (M + 1)] = a_lb.ravel(order="F")
    ubx[1:1 + 4 * (M + 1)] = a_ub.ravel(order="F")
    unpack = ca.Function("unpack", [w], [T, alpha, Xs, Xc, QA_of_alpha])
    lift = ca.Function("lift", [alpha], [QA_of_alpha])
    return _Problem(nlp, lift, lbx, ubx, np.concatenate(lbg), np.concatenate(ubg), groups, unpack,
                    cost_scale)


def initial_guess(model, opts: GaitOptions):
    """Built-in guess: a symmetric double-support pose at impact with both knees bent,
    joints interpolated linearly in s, a swing-knee bend mid-step for clearance."""
    M, N, d = opts.bezier_degree, opts.n_intervals, opts.degree
    lo, hi = opts.step_length_bounds
    L0 = float(np.clip(0.45 * np.sqrt(opts.speed / 0.75), lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo)))
    T0 = float(np.clip(L0 / opts.speed, *opts.step_time_bounds))
    kappa, lean = 0.15, 0.05
    from scipy.optimize import brentq  # local import: only the guess needs it
    p = model.params
    a = brentq(lambda a: p.L_tibia * np.sin(a) + p.L_femur * np.sin(a - kappa)
               + p.L_femur * np.sin(a) + p.L_tibia * np.sin(a - kappa) - L0, 0.0, 1.2)
    phi = np.array([a, a - kappa, lean, -a, kappa - a])  # femur_sw = -a, tibia_sw = kappa - a
    qT = np.r_[phi[0], np.diff(phi)]
    q0 = model.E @ qT
    qa0, qaT = q0[1:], qT[1:]
    k = np.arange(M + 1) / M
    alpha = qa0[:, None] + k[None, :] * (qaT - qa0)[:, None]
    alpha[3] += 0.8 * np.sin(np.pi * k)          # swing knee bends mid-step
    alpha[0] = np.minimum(alpha[0], opts.stance_knee_max - 0.02)
    alpha[3] = np.maximum(alpha[3], opts.swing_knee_min + 0.02)
    tau, *_ = _collocation(opts)
    s_start = np.arange(N + 1) / N
    s_coll = (np.arange(N)[:, None] / N + tau[None, :] / N).ravel()
    dqu = (qT[0] - q0[0]) / T0
    Xs = np.vstack([q0[0] + s_start * (qT[0] - q0[0]), np.full(N + 1, dqu)])
    Xc = np.vstack([q0[0] + s_coll * (qT[0] - q0[0]), np.full(s_coll.size, dqu)])
    return _stack(model, opts, T0, alpha, Xs, Xc)


def _stack(model, opts, T, alpha, Xs, Xc):
    """Decision vector from (T, alpha, Xs, Xc); the lifted actuated values follow alpha."""
    ref = reference_dynamics(model, opts.bezier_degree)
    tau, *_ = _collocation(opts)
    N = opts.n_intervals
    s_all = np.r_[np.arange(N + 1) / N, (np.arange(N)[:, None] / N + tau[None, :] / N).ravel()]
    QA = np.vstack([np.array(v) for v in ref.qa.map(s_all.size)(alpha, s_all[None, :], 1.0)])
    return np.concatenate([[T], np.asarray(alpha).ravel(order="F"), Xs.ravel(order="F"),
                           Xc.ravel(order="F"), QA.ravel(order="F")])


def _violations(prob: _Problem, gval: np.ndarray, tol: float):
    bad = []
    for name, a, b in prob.groups:
        v = np.maximum(prob.lbg[a:b] - gval[a:b], gval[a:b] - prob.ubg[a:b])
        if v.size and np.max(v) > tol:
            bad.append((name, float(np.max(v))))
    return sorted(bad, key=lambda t: -t[1])


def _polish(model, opts, alpha, x0, T, tol=1e-12, max_iter=20):
    """Minimum-norm Newton on (alpha, x0, T) for the exact periodic orbit (module doc)."""
    ref = reference_dynamics(model, opts.bezier_degree)
    n = opts.polish_steps
    F = ref.integrate(n)
    p = ca.MX.sym("p", 4 * (opts.bezier_degree + 1) + 3)
    na = 4 * (opts.bezier_degree + 1)
    a = ca.reshape(p[:na], 4, opts.bezier_degree + 1)
    xs0 = p[na:na + 2]
    Tm = p[na + 2]
    X = F(xs0, 0, 1.0 / n, a, Tm)
    x1 = X[:, -1]
    qa0, dqa0, _ = ref.qa(a, 0, Tm)
    qa1, dqa1, _ = ref.qa(a, 1, Tm)
    qm = ca.vertcat(x1[0], qa1)
    dqm = ca.vertcat(x1[1], dqa1)
    qp, dqp = model.impact(qm, dqm)
    xe, ze = model.swing_foot(qm)
    r = ca.vertcat(qp - ca.vertcat(xs0[0], qa0), dqp - ca.vertcat(xs0[1], dqa0), ze,
                   xe - opts.speed * Tm)
    rf = ca.Function("polish_residual", [p], [r, ca.jacobian(r, p)])
    pv = np.r_[np.asarray(alpha).ravel(order="F"), x0, T]
    hist = []
    for _ in range(max_iter):
        rv, Jv = (np.array(v) for v in rf(pv))
        rv = rv.ravel()
        hist.append(float(np.max(np.abs(rv))))
        if hist[-1] <= tol or (len(hist) > 3 and hist[-1] < 1e-10 and hist[-1] >= hist[-2]):
            break      # converged, or stagnating at round-off
        pv = pv - np.linalg.lstsq(Jv, rv, rcond=None)[0]
    else:
        raise GaitOptimizationError(
            f"polish (Newton on the exact periodic orbit) did not converge: residual "
            f"{hist[-1]:.2e} after {max_iter} iterations; try more n_intervals")
    a_new = pv[:na].reshape(4, -1, order="F")
    return a_new, pv[na:na + 2], float(pv[na + 2]), hist


def optimize_gait(model, options: GaitOptions | None = None, *, verbose: bool = False,
                  warm_start=None, **overrides):
    """Solve the reference-gait problem of SPEC section 2 and return a :class:`Gait`.

    ``options`` is a :class:`GaitOptions`; keyword ``overrides`` replace single fields
    (``optimize_gait(m, speed=1.0)``).  ``warm_start`` may be a previous :class:`Gait`
    of the same Bezier degree.  Raises :class:`GaitOptimizationError` with IPOPT's status
    and the violated constraint families when no feasible gait is found.
    """
    from .gait import Gait

    opts = options or GaitOptions()
    if not isinstance(opts, GaitOptions):
        raise ValueError(f"options must be GaitOptions, got {type(opts).__name__}")
    if overrides:
        opts = opts.replace(**overrides)
    t0 = time.perf_counter()
    prob = _build_problem(model, opts)
    ipopt = {"print_level": 5 if verbose else 0, "tol": 1e-9, "max_iter": 1000,
             "mu_strategy": "adaptive", "linear_solver": "mumps", "sb": "yes"}
    ipopt.update(opts.ipopt)
    solver = ca.nlpsol("gait_nlp", "ipopt", prob.nlp,
                       {"ipopt": ipopt, "print_time": False, "expand": opts.expand,
                        "error_on_fail": False})
    t_build = time.perf_counter() - t0
    w0 = initial_guess(model, opts) if warm_start is None else _warm(model, opts, warm_start)
    sol = solver(x0=w0, lbx=prob.lbx, ubx=prob.ubx, lbg=prob.lbg, ubg=prob.ubg)
    stats = solver.stats()
    t_solve = time.perf_counter() - t0 - t_build
    gval = np.array(sol["g"]).ravel()
    viol = _violations(prob, gval, 1e-6)
    status = stats.get("return_status", "unknown")
    if not stats.get("success", False) or viol:
        fam = ", ".join(f"{n} (by {v:.3g})" for n, v in viol[:4]) or "none above 1e-6"
        raise GaitOptimizationError(
            f"IPOPT status '{status}' after {stats.get('iter_count', '?')} iterations at "
            f"speed {opts.speed} m/s; violated constraint families: {fam}. Try other "
            f"bounds (speed, mu, torque_limit, step_length_bounds) or more iterations.")
    T, alpha, Xs, Xc, _ = (np.array(v) for v in prob.unpack(sol["x"]))
    T = float(T.item())
    alpha_p, x0_p, T_p, hist = _polish(model, opts, alpha, Xs[:, 0], T)
    t_total = time.perf_counter() - t0
    solver_stats = dict(status=status, iterations=int(stats.get("iter_count", -1)),
                        build_time=t_build, solve_time=t_solve, total_time=t_total,
                        ipopt_cost=float(sol["f"]) / prob.cost_scale,
                        polish_residuals=hist,
                        polish_change=float(np.max(np.abs(np.r_[(alpha_p - alpha).ravel(),
                                                                x0_p - Xs[:, 0], T_p - T]))))
    return Gait(model, opts, alpha_p, x0_p, T_p, solver_stats=solver_stats)


def _warm(model, opts, gait):
    if gait.alpha.shape != (4, opts.bezier_degree + 1):
        raise ValueError("warm_start gait has another bezier_degree")
    tau, *_ = _collocation(opts)
    N = opts.n_intervals
    s_start = np.arange(N + 1) / N
    s_coll = (np.arange(N)[:, None] / N + tau[None, :] / N).ravel()
    Xs = np.vstack([gait.q(s_start * gait.T)[0], gait.dq(s_start * gait.T)[0]])
    Xc = np.vstack([gait.q(s_coll * gait.T)[0], gait.dq(s_coll * gait.T)[0]])
    return _stack(model, opts, gait.T, gait.alpha, Xs, Xc)
