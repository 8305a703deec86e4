"""Direct collocation of RABBIT's cyclic walking step (SPEC section 2), then a polish
that makes the unactuated trajectory exact.

Transcription.  The actuated joints are Bezier polynomials of s = t / T (so q_a^d,
dq_a^d, ddq_a^d are exact everywhere and continue past T); only the unactuated row of
eq. (1) is an ODE, x = (q_u, dq_u), and it is transcribed by orthogonal collocation
(Legendre by default: order 2d at interval ends, i.e. 6 for d = 3, with the same number
of variables as Radau; Radau is available for comparison, see benchmarks/bench_gait.py).
Path constraints (torques, contact force, friction cone, swing-foot clearance) are
imposed at every interval boundary and collocation point; knee limits on the Bezier
coefficients, which bounds the polynomial on the whole step (convex hull).

Exact Hessian with structure.  The actuated joints are lifted at every point: variables
QA_k = (q_a, dq_a/ds, d2q_a/ds2) at point k, tied to alpha by linear equalities.  Every
nonlinear term of the NLP is then either a function of one point's
z_k = (x_k, QA_k, T) (15 numbers) or of the boundary variables (T, alpha, x(0), x(1)) of
the impact and periodicity conditions.  The constraints and the cost are *linear* in the
point outputs (collocation right-hand side, torques, contact forces, swing height, cost
density), so the Hessian of the Lagrangian is

    sum_k P_k' [sum_j c_kj d2 out_kj / dz_k2] P_k + P_b' d2 (lam_b' g_b) P_b,

with c_k the multipliers pulled back through that linear map.  The 15x15 point Hessian
and the 33x33 boundary Hessian are exact SX Hessians by AD (built once), mapped over the
points and scattered into the global upper-triangular sparsity; the constraint Jacobian
and the cost gradient are assembled the same way from 10x15 point Jacobians.  IPOPT
gets exact derivatives at a fraction of the cost of differentiating the MX graph
(``derivatives='casadi'`` keeps that route as the baseline; benchmarks/bench_gait.py).

Cost.  The default cost is (integral of u'u dt) / step length.  With the speed
constraint x_end = v T, it equals (1/v) * integral_0^1 u'u ds (s = t / T): the two
objectives agree on the whole feasible set, so the NLPs have the same solutions, and
the second is a sum of per-point terms (no coupling through x_end), which is what makes
the Hessian separable.  'torque_squared' is T * integral_0^1 u'u ds, also per point.
Quadrature: the collocation (Gauss/Radau) weights.

Polish.  Collocation satisfies the dynamics at the nodes only.  The exported reference
takes q_u^d as the ODE solution from (q_u(0), dq_u(0)) (fine RK4) and a minimum-norm
Newton iteration on all parameters (alpha, x0, T), with the exact Jacobian by forward
sensitivities of every RK4 step (AD), restores periodicity through the impact,
z_sw(T) = 0 and the speed to ~1e-12.  The corrections are of the size of the
collocation error (4e-11 in the parameters at the default transcription, whose q_u
polynomial is within 7e-8 rad of the exact solution between the nodes; see
benchmarks/bench_gait.py), far below the inequality margins.

Between the nodes.  The path constraints are imposed at the nodes only; the polished
gait is checked on a dense grid (Gait.violations) and, where an active constraint is
exceeded between nodes, its node bound is tightened and the problem re-solved from the
gait found (optimize_gait).  The default gait and those at 0.5 and 1.0 m/s need no
such pass.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from functools import lru_cache

import casadi as ca
import numpy as np

from .options import GaitOptions
from .reference import reference_dynamics

__all__ = ["optimize_gait", "GaitOptimizationError", "initial_guess", "build_problem",
           "solve_collocation", "CollocationResult"]

#: rows of a point's output vector (see _point_functions)
_OUT = dict(f=slice(0, 2), u=slice(2, 6), Fx=6, Fz=7, zsw=8, cost=9)
_N_OUT = 10
_N_Z = 15          # z_k = (q_u, dq_u, q_a, dq_a/ds, d2q_a/ds2, T)


class GaitOptimizationError(RuntimeError):
    """IPOPT did not find a feasible gait; the message names the status and the
    constraint families that are violated at the last iterate."""

    def __init__(self, message, status=None, violations=None):
        super().__init__(message)
        self.status = status
        self.violations = list(violations or [])


@dataclass
class Problem:
    """The transcribed NLP: ``nlp`` (x, f, g), bounds, the constraint families
    ``groups`` (name, start, stop) in g, ``unpack`` w -> (T, alpha, Xs, Xc, QA), and the
    structured exact derivatives in nlpsol's signatures: ``hess_lag`` (x, p, lam_f,
    lam_g) -> triu(H), ``jac_g`` (x, p) -> (g, dg/dx), ``grad_f`` (x, p) -> (f, df/dx)."""

    nlp: dict
    lift: ca.Function
    lbx: np.ndarray
    ubx: np.ndarray
    lbg: np.ndarray
    ubg: np.ndarray
    groups: list
    unpack: ca.Function
    cost_scale: float
    hess_lag: ca.Function
    jac_g: ca.Function
    grad_f: ca.Function
    s_all: np.ndarray


def _collocation(opts):
    tau = ca.collocation_points(opts.degree, opts.scheme)
    C, Dend, Bq = ca.collocation_coeff(tau)
    return np.array(tau), np.array(C), np.array(Dend).ravel(), np.array(Bq).ravel()


def _grid(opts):
    """s of every constrained point: interval starts (0..N), then collocation points."""
    tau, *_ = _collocation(opts)
    N = opts.n_intervals
    s_start = np.arange(N + 1) / N
    s_coll = (np.arange(N)[:, None] / N + tau[None, :] / N).ravel()
    return s_start, s_coll


@lru_cache(maxsize=16)
def _point_functions(model, bezier_degree: int, cost: str):
    """Per-point outputs and their exact Hessian (SX, built once per model and cost).

    ``point(z)`` -> out = (T dq_u, T ddq_u, u (4), Fx, Fz, z_sw, cost density), with
    z = (q_u, dq_u, q_a, dq_a/ds, d2q_a/ds2, T): the first two outputs are the
    unactuated row of eq. (1) as an ODE in s; the cost density is u'u (per-length cost,
    times 1/v outside) or T u'u ('torque_squared').
    ``point_jac(z)`` -> (out, d out / dz); ``point_cost(z)`` -> (cost density, gradient);
    ``point_hess(z, c)`` -> upper triangle of d2(c' out)/dz2 (15x15).
    """
    ref = reference_dynamics(model, bezier_degree)
    z = ca.SX.sym("z", _N_Z)
    x, lifted, T = z[0:2], z[2:14], z[14]
    q = ca.vertcat(x[0], lifted[:4])
    dq = ca.vertcat(x[1], lifted[4:8] / T)
    ddqa = lifted[8:12] / T**2
    ddq = ca.vertcat(ref.ddqu(q, dq, ddqa), ddqa)
    u = ref.torque(q, dq, ddq)
    Fx, Fz = model.ground_reaction_acc(q, dq, ddq)
    _, zsw = model.swing_foot(q)
    density = ca.sumsqr(u) * (T if cost == "torque_squared" else 1)
    # common subexpression elimination first: the model's expressions repeat a lot
    # (3587 -> 1636 operations), which halves the size of the Hessian below
    out = ca.cse(ca.vertcat(T * ca.vertcat(x[1], ddq[0]), u, Fx, Fz, zsw, density))
    density = out[-1]
    point = ca.Function("point", [z], [out], ["z"], ["out"])
    point_jac = ca.Function("point_jac", [z], [out, ca.jacobian(out, z)], ["z"], ["out", "J"])
    point_cost = ca.Function("point_cost", [z], [density, ca.gradient(density, z)], ["z"],
                             ["density", "grad"])
    c = ca.SX.sym("c", _N_OUT)
    H = ca.triu(ca.hessian(ca.dot(c, out), z)[0])
    point_hess = ca.Function("point_hess", [z, c], [H], ["z", "c"], ["H"])
    return point, point_jac, point_cost, point_hess


def _boundary_function(model, opts: GaitOptions):
    """End of step, impact (paper eq. 2-3) and periodicity, as SX of
    v_b = (T, vec(alpha), x(0), x(1)); returns (Function, [(name, rows, lo, hi)])."""
    ref = reference_dynamics(model, opts.bezier_degree)
    M = opts.bezier_degree
    vb = ca.SX.sym("vb", 1 + 4 * (M + 1) + 4)
    T = vb[0]
    alpha = ca.reshape(vb[1:1 + 4 * (M + 1)], 4, M + 1)
    x0, x1 = vb[-4:-2], vb[-2:]
    qa0, dqa0, _ = ref.qa(alpha, 0, T)
    qa1, dqa1, _ = ref.qa(alpha, 1, T)
    q_minus = ca.vertcat(x1[0], qa1)
    dq_minus = ca.vertcat(x1[1], dqa1)
    q_plus, dq_plus, F_imp, _, v_old = model.impact_full(q_minus, dq_minus)
    x_end, z_end = model.swing_foot(q_minus)
    _, dz_end = model.swing_foot_velocity(q_minus, dq_minus)
    mu, inf = opts.mu, np.inf
    families = [
        ("periodicity (q)", q_plus - ca.vertcat(x0[0], qa0), 0, 0),
        ("periodicity (dq)", dq_plus - ca.vertcat(x0[1], dqa0), 0, 0),
        ("swing foot on ground at T", z_end, 0, 0),
        ("speed", x_end - opts.speed * T, 0, 0),
        ("step length", x_end, *opts.step_length_bounds),
        ("strike velocity", dz_end, -inf, -opts.min_strike_speed),
        ("lift-off velocity", v_old[1], opts.min_liftoff_speed, inf),
        ("impact impulse cone", ca.vertcat(F_imp[1], mu * F_imp[1] - F_imp[0],
                                           mu * F_imp[1] + F_imp[0]), 0, inf),
    ]
    g = ca.cse(ca.vertcat(*[f[1] for f in families]))
    lam = ca.SX.sym("lam", g.numel())
    Hb = ca.triu(ca.hessian(ca.dot(lam, g), vb)[0])
    bnd = ca.Function("boundary", [vb], [g, ca.jacobian(g, vb)], ["vb"], ["g", "J"])
    bnd_hess = ca.Function("boundary_hess", [vb, lam], [Hb], ["vb", "lam"], ["H"])
    return bnd, bnd_hess, families


#: path-constraint families that between-node violations can be fixed for, by tightening
#: the node constraints: family -> unit of the margin
MARGINS = {"torque limit": "N m", "normal force": "N", "friction cone": "(ratio)",
           "swing-foot clearance": "m"}
#: dense-grid families (Gait.violations) fixed by another family's margin
_FIXED_BY = {"swing foot above ground": "swing-foot clearance"}


def build_problem(model, opts: GaitOptions, margins: dict | None = None) -> Problem:
    """Transcribe the SPEC section 2 problem for ``opts`` (see the module docstring).

    ``margins`` (family of :data:`MARGINS` -> amount) tightens the path constraints at
    the nodes, so that they hold between the nodes too (see :func:`optimize_gait`)."""
    margins = dict(margins or {})
    unknown = set(margins) - set(MARGINS)
    if unknown:
        raise ValueError(f"margins: unknown constraint families {sorted(unknown)}")
    ref = reference_dynamics(model, opts.bezier_degree)
    M, N, d = opts.bezier_degree, opts.n_intervals, opts.degree
    tau, C, Dend, Bq = _collocation(opts)
    h = 1.0 / N
    s_start, s_coll = _grid(opts)
    s_all = np.r_[s_start, s_coll]
    npts = s_all.size
    na = 4 * (M + 1)

    # decision variables, in this order in w
    T = ca.MX.sym("T")
    alpha = ca.MX.sym("alpha", 4, M + 1)
    Xs = ca.MX.sym("Xs", 2, N + 1)
    Xc = ca.MX.sym("Xc", 2, N * d)
    QA = ca.MX.sym("QA", 12, npts)          # (qa, dqa/ds, d2qa/ds2) at every point
    w = ca.veccat(T, alpha, Xs, Xc, QA)
    nw = w.numel()
    off_a, off_Xs = 1, 1 + na
    off_Xc = off_Xs + 2 * (N + 1)
    off_QA = off_Xc + 2 * N * d
    X_all = ca.horzcat(Xs, Xc)

    s_sym = ca.SX.sym("s")
    a_sx = ca.SX.sym("alpha", 4, M + 1)
    qa_s, dqa_s, ddqa_s = ref.qa(a_sx, s_sym, 1.0)       # with T = 1: s-derivatives
    basis = ca.Function("basis", [a_sx, s_sym], [ca.vertcat(qa_s, dqa_s, ddqa_s)])
    QA_of_alpha = basis.map(npts)(alpha, ca.DM(s_all).T)

    # ---- constraints and cost as functions of w and of the point outputs OUT
    OUT = ca.MX.sym("OUT", _N_OUT, npts)
    g, lbg, ubg, groups = [], [], [], []

    def add(name, expr, lo, hi):
        expr = ca.vec(expr)
        n = expr.numel()
        start = sum(e.numel() for e in g)
        g.append(expr)
        lbg.append(np.broadcast_to(lo, (n,)).astype(float))
        ubg.append(np.broadcast_to(hi, (n,)).astype(float))
        groups.append((name, start, start + n))

    f_coll = OUT[_OUT["f"], N + 1:]
    coll, cont = [], []
    for k in range(N):
        Z = ca.horzcat(Xs[:, k], Xc[:, k * d:(k + 1) * d])
        coll.append(ca.mtimes(Z, C) - h * f_coll[:, k * d:(k + 1) * d])
        cont.append(ca.mtimes(Z, Dend) - Xs[:, k + 1])
    add("actuated joints (Bezier)", QA - QA_of_alpha, 0, 0)
    add("dynamics (collocation)", ca.horzcat(*coll), 0, 0)
    add("dynamics (continuity)", ca.horzcat(*cont), 0, 0)

    umax = opts.torque_limit - margins.get("torque limit", 0.0)
    mu = opts.mu - margins.get("friction cone", 0.0)
    Fx_all, Fz_all = OUT[_OUT["Fx"], :], OUT[_OUT["Fz"], :]
    add("torque limit", OUT[_OUT["u"], :], -umax, umax)
    add("normal force", Fz_all, opts.min_normal_force + margins.get("normal force", 0.0), np.inf)
    add("friction cone", ca.vertcat(mu * Fz_all - Fx_all, mu * Fz_all + Fx_all), 0, np.inf)
    idx = np.flatnonzero((s_all > 1e-9) & (s_all < 1 - 1e-9))
    clear = (opts.clearance * 4 * s_all[idx] * (1 - s_all[idx])
             + margins.get("swing-foot clearance", 0.0))
    add("swing-foot clearance", OUT[_OUT["zsw"], idx.tolist()] - ca.DM(clear).T, 0, np.inf)
    n_linear = sum(e.numel() for e in g)

    bnd, bnd_hess, families = _boundary_function(model, opts)
    vb_index = np.r_[0, off_a + np.arange(na), off_Xs + np.arange(2), off_Xs + 2 * N + np.arange(2)]
    g_b, _ = bnd(ca.vertcat(T, ca.vec(alpha), Xs[:, 0], Xs[:, N]))
    row = 0
    for name, expr, lo, hi in families:
        n = expr.numel()
        add(name, g_b[row:row + n], lo, hi)
        row += n

    # cost: (1/v) int_0^1 u'u ds  (= int u'u dt / step length when x_end = v T), or
    # T int_0^1 u'u ds; Gauss/Radau quadrature at the collocation points
    weights = np.r_[np.zeros(N + 1), np.tile(Bq, N) * h]
    if opts.cost == "torque_squared_per_length":
        weights = weights / opts.speed
    cost_scale = 1e-3
    J_of_out = cost_scale * ca.mtimes(OUT[_OUT["cost"], :], ca.DM(weights))

    g_of_out = ca.vertcat(*g)
    # the point outputs enter g and f linearly, and the other terms of g are linear in w
    # (or the boundary function): constant pull-back maps
    jac = ca.Function("pullback", [w, OUT], [ca.jacobian(g_of_out[:n_linear], OUT),
                                             ca.jacobian(g_of_out[:n_linear], w),
                                             ca.vec(ca.gradient(J_of_out, OUT))])
    A_out, G_w, a_out = jac(np.zeros(w.numel()), np.zeros(OUT.shape))
    check = jac(np.linspace(-1, 1, w.numel()), np.ones(OUT.shape))
    if any(float(ca.mmax(ca.fabs(a - b))) > 1e-12 for a, b in zip((A_out, G_w, a_out), check)):
        raise AssertionError("internal: constraints must be linear in w and the point outputs")

    point, point_jac, point_cost, point_hess = _point_functions(model, M, opts.cost)
    Z_all = ca.vertcat(X_all, QA, ca.repmat(T, 1, npts))
    out_all = point.map(npts)(Z_all)
    gfun = ca.Function("g_of_out", [w, OUT], [g_of_out])
    ffun = ca.Function("f_of_out", [w, OUT], [J_of_out])
    nlp = {"x": w, "f": ffun(w, out_all), "g": gfun(w, out_all)}

    z_index = np.empty((_N_Z, npts), dtype=int)
    for k in range(npts):
        xk = off_Xs + 2 * k if k <= N else off_Xc + 2 * (k - N - 1)
        z_index[:, k] = np.r_[xk, xk + 1, off_QA + 12 * k + np.arange(12), 0]
    xw = ca.MX.sym("x", nw)
    pw = ca.MX.sym("p", 0, 1)
    z_all = ca.reshape(xw[z_index.ravel(order="F").tolist()], _N_Z, npts)
    vb_w = xw[vb_index.tolist()]

    # ---- structured constraint Jacobian and objective gradient:
    # d vec(OUT)/dw is block sparse (one 10x15 block J_k per point, columns z_index)
    sp_j = point_jac.sparsity_out(1)
    rj, cj = (np.array(v) for v in sp_j.get_triplet())
    ks = np.repeat(np.arange(npts), rj.size)
    dout_sp = ca.Sparsity.triplet(_N_OUT * npts, nw, (ks * _N_OUT + np.tile(rj, npts)).tolist(),
                                  z_index[np.tile(cj, npts), ks].tolist())
    out_v, Jp = point_jac.map(npts)(z_all)
    # the map's nonzeros are block after block, column-major within a block; the
    # triplet sparsity orders them column-major globally: permute
    order = np.lexsort(((ks * _N_OUT + np.tile(rj, npts)), z_index[np.tile(cj, npts), ks]))
    dout = ca.MX(dout_sp, Jp.nz[order.tolist()])
    g_b, Jb = bnd(vb_w)
    select_b = ca.DM(ca.Sparsity.triplet(vb_index.size, nw, list(range(vb_index.size)),
                                         vb_index.tolist()), 1.0)
    g_w = ca.densify(gfun(xw, out_v))
    jac_g = ca.vertcat(G_w + ca.mtimes(A_out, dout), ca.mtimes(Jb, select_b))
    jac_g_fun = ca.Function("jac_g", [xw, pw], [g_w, jac_g], ["x", "p"], ["g", "jac_g_x"])
    # objective: only the cost density of the collocation points (weights a_k)
    wk = np.array(a_out).ravel()[_OUT["cost"]::_N_OUT]
    cpts = np.flatnonzero(wk)
    dens, dgrad = point_cost.map(cpts.size)(z_all[:, cpts.tolist()])
    f_w = ca.mtimes(dens, ca.DM(wk[cpts]))
    grad_w = ca.densify(ca.mtimes(ca.DM(ca.Sparsity.triplet(
        nw, _N_Z * cpts.size, z_index[:, cpts].ravel(order="F").tolist(),
        list(range(_N_Z * cpts.size))), 1.0), ca.vec(dgrad * ca.repmat(ca.DM(wk[cpts]).T, _N_Z, 1))))
    grad_f_fun = ca.Function("grad_f", [xw, pw], [f_w, grad_w], ["x", "p"], ["f", "grad_f_x"])

    # ---- structured exact Hessian of the Lagrangian
    sp_p = point_hess.sparsity_out(0)
    sp_b = bnd_hess.sparsity_out(0)
    rp, cp = (np.array(v) for v in sp_p.get_triplet())
    rb, cb = (np.array(v) for v in sp_b.get_triplet())
    # global (row, col) of every contribution, in the order of the nonzeros below
    R = np.r_[z_index[rp, :].T.ravel(), vb_index[rb]]
    Cc = np.r_[z_index[cp, :].T.ravel(), vb_index[cb]]
    R, Cc = np.minimum(R, Cc), np.maximum(R, Cc)           # upper triangle
    lin = Cc * nw + R                                      # column-major order
    uniq, where = np.unique(lin, return_inverse=True)
    H_sp = ca.Sparsity.triplet(nw, nw, (uniq % nw).tolist(), (uniq // nw).tolist())
    scatter = ca.DM(ca.Sparsity.triplet(uniq.size, lin.size, where.tolist(),
                                        list(range(lin.size))), 1.0)
    lam_f = ca.MX.sym("lam_f")
    lam_g = ca.MX.sym("lam_g", g_of_out.numel())
    c_all = ca.reshape(ca.mtimes(A_out.T, lam_g[:n_linear]) + lam_f * a_out, _N_OUT, npts)
    Hp = point_hess.map(npts)(z_all, c_all)
    Hb = bnd_hess(vb_w, lam_g[n_linear:])
    contrib = ca.vertcat(Hp.nz[:], Hb.nz[:])
    H = ca.MX(H_sp, ca.mtimes(scatter, contrib))
    hess_lag = ca.Function("hess_lag", [xw, pw, lam_f, lam_g], [H],
                           ["x", "p", "lam_f", "lam_g"], ["triu_hess_gamma_x_x"])

    # ---- variable bounds: T, knee limits on the Bezier coefficients, joint angles sane
    lbx = np.full(nw, -np.inf)
    ubx = np.full(nw, np.inf)
    lbx[0], ubx[0] = opts.step_time_bounds
    a_lb = np.full((4, M + 1), -np.pi)
    a_ub = np.full((4, M + 1), np.pi)
    a_ub[0, :] = opts.stance_knee_max
    a_lb[3, :] = opts.swing_knee_min
    lbx[off_a:off_a + na] = a_lb.ravel(order="F")
    ubx[off_a:off_a + na] = a_ub.ravel(order="F")
    unpack = ca.Function("unpack", [w], [T, alpha, Xs, Xc, QA_of_alpha])
    lift = ca.Function("lift", [alpha], [QA_of_alpha])
    return Problem(nlp, lift, lbx, ubx, np.concatenate(lbg), np.concatenate(ubg), groups,
                   unpack, cost_scale, hess_lag, jac_g_fun, grad_f_fun, s_all)


def initial_guess(model, opts: GaitOptions):
    """Built-in guess: a symmetric double-support pose at impact with both knees bent,
    joints interpolated linearly in s, a swing-knee bend mid-step for clearance."""
    M = opts.bezier_degree
    lo, hi = opts.step_length_bounds
    L0 = float(np.clip(0.45 * np.sqrt(opts.speed / 0.75), lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo)))
    T0 = float(np.clip(L0 / opts.speed, *opts.step_time_bounds))
    kappa, lean = 0.15, 0.05
    p = model.params
    # both legs bent by kappa, feet L0 apart: (L_t + L_f)(sin a + sin(a - kappa)) = L0,
    # i.e. 2 (L_t + L_f) cos(kappa/2) sin(a - kappa/2) = L0
    ratio = L0 / (2 * (p.L_tibia + p.L_femur) * np.cos(kappa / 2))
    a = kappa / 2 + float(np.arcsin(np.clip(ratio, -0.95, 0.95)))
    phi = np.array([a, a - kappa, lean, -a, kappa - a])  # femur_sw = -a, tibia_sw = kappa - a
    qT = np.r_[phi[0], np.diff(phi)]
    q0 = model.E @ qT
    qa0, qaT = q0[1:], qT[1:]
    k = np.arange(M + 1) / M
    alpha = qa0[:, None] + k[None, :] * (qaT - qa0)[:, None]
    alpha[3] += 0.8 * np.sin(np.pi * k)          # swing knee bends mid-step
    alpha[0] = np.minimum(alpha[0], opts.stance_knee_max - 0.02)
    alpha[3] = np.maximum(alpha[3], opts.swing_knee_min + 0.02)
    s_start, s_coll = _grid(opts)
    dqu = (qT[0] - q0[0]) / T0
    Xs = np.vstack([q0[0] + s_start * (qT[0] - q0[0]), np.full(s_start.size, dqu)])
    Xc = np.vstack([q0[0] + s_coll * (qT[0] - q0[0]), np.full(s_coll.size, dqu)])
    return _stack(model, opts, T0, alpha, Xs, Xc)


def _stack(model, opts, T, alpha, Xs, Xc):
    """Decision vector from (T, alpha, Xs, Xc); the lifted actuated values follow alpha."""
    ref = reference_dynamics(model, opts.bezier_degree)
    s_all = np.concatenate(_grid(opts))
    QA = np.vstack([np.array(v) for v in ref.qa.map(s_all.size)(alpha, s_all[None, :], 1.0)])
    return np.concatenate([[T], np.asarray(alpha).ravel(order="F"), Xs.ravel(order="F"),
                           Xc.ravel(order="F"), QA.ravel(order="F")])


#: units of each constraint family's residual, for messages
UNITS = {
    "actuated joints (Bezier)": "rad", "dynamics (collocation)": "rad",
    "dynamics (continuity)": "rad", "torque limit": "N m", "normal force": "N",
    "friction cone": "N", "swing-foot clearance": "m", "periodicity (q)": "rad",
    "periodicity (dq)": "rad/s", "swing foot on ground at T": "m", "speed": "m",
    "step length": "m", "strike velocity": "m/s", "lift-off velocity": "m/s",
    "impact impulse cone": "N s",
}


def _violations(prob: Problem, gval: np.ndarray, tol: float = 1e-6):
    """[(family, worst violation)] of the constraint families violated by more than
    ``tol`` * max(1, |bound|) (IPOPT relaxes bounds by about that much), worst first."""
    bad = []
    for name, a, b in prob.groups:
        lo, hi, gv = prob.lbg[a:b], prob.ubg[a:b], gval[a:b]
        with np.errstate(invalid="ignore"):
            v = np.maximum(lo - gv, gv - hi)
            scale = np.maximum(1.0, np.where(lo - gv > gv - hi, np.abs(lo), np.abs(hi)))
        v = np.where(np.isnan(gv), np.inf, v)
        if v.size and np.any(v > tol * scale):
            bad.append((name, float(np.max(v))))
    return sorted(bad, key=lambda t: -t[1])


def describe_violations(viol, limit: int = 4) -> str:
    """'speed (off by 0.7 m); torque limit (off by 3 N m)' for the worst families."""
    text = "; ".join(f"{n} (off by {v:.3g} {UNITS.get(n, '')})".replace(" )", ")")
                     for n, v in viol[:limit])
    if len(viol) > limit:
        text += f"; and {len(viol) - limit} more"
    return text or "none"


def _check_reachable(opts: GaitOptions):
    """The speed constraint x_end = v T with the step-length and step-time bounds."""
    (l_lo, l_hi), (t_lo, t_hi) = opts.step_length_bounds, opts.step_time_bounds
    v_lo, v_hi = l_lo / t_hi, l_hi / t_lo
    if not v_lo <= opts.speed <= v_hi:
        raise GaitOptimizationError(
            f"no feasible gait: speed {opts.speed:g} m/s is out of reach of "
            f"step_length_bounds ({l_lo:g}, {l_hi:g}) m and step_time_bounds ({t_lo:g}, "
            f"{t_hi:g}) s, which allow {v_lo:.3g} to {v_hi:.3g} m/s; violated constraint "
            f"family: speed. IPOPT was not run (status 'not_run'). Try a speed in that "
            f"range or wider bounds.", status="not_run",
            violations=[("speed", float(max(v_lo - opts.speed, opts.speed - v_hi)))])


@lru_cache(maxsize=16)
def _polish_function(model, bezier_degree: int, n_steps: int):
    """(p = (vec alpha, x0, T)) -> (x(1), dx(1)/dp): n RK4 steps of the unactuated row
    with forward sensitivities propagated step by step (exact Jacobian of the discrete
    integrator, by AD of one step)."""
    ref = reference_dynamics(model, bezier_degree)
    na = 4 * (bezier_degree + 1)
    x = ca.SX.sym("x", 2)
    S = ca.SX.sym("S", 2, na + 3)
    s = ca.SX.sym("s")
    ds = ca.SX.sym("ds")
    a = ca.SX.sym("alpha", 4, bezier_degree + 1)
    T = ca.SX.sym("T")
    xn, sn = ref.rk4(x, s, ds, a, T)
    J = ca.jacobian(xn, ca.vertcat(ca.vec(a), x, T))
    Sn = ca.mtimes(J[:, na:na + 2], S) + ca.horzcat(J[:, :na], ca.SX.zeros(2, 2), J[:, na + 2])
    step = ca.Function("rk4_sens", [x, S, s, ds, a, T], [xn, Sn, sn])
    acc = step.mapaccum("rk4_sens_acc", n_steps, [0, 1, 2], [0, 1, 2])
    p = ca.MX.sym("p", na + 3)
    am = ca.reshape(p[:na], 4, bezier_degree + 1)
    S0 = ca.horzcat(ca.MX.zeros(2, na), ca.MX.eye(2), ca.MX.zeros(2, 1))
    X, SS, _ = acc(p[na:na + 2], S0, 0, 1.0 / n_steps, am, p[na + 2])
    with_sens = ca.Function("unactuated_flow_sens", [p], [X[:, -1], SS[:, -(na + 3):]],
                            ["p"], ["x1", "dx1_dp"])
    X = ref.integrate(n_steps)(p[na:na + 2], 0, 1.0 / n_steps, am, p[na + 2])
    plain = ca.Function("unactuated_flow", [p], [X[:, -1]], ["p"], ["x1"])
    return plain, with_sens


@lru_cache(maxsize=16)
def _periodicity_residual(model, bezier_degree: int):
    """(p, x(1), speed) -> residual (impact+relabel - start (10), z_sw(T), x_sw(T) - v T)
    and its Jacobians in p and x(1)."""
    ref = reference_dynamics(model, bezier_degree)
    na = 4 * (bezier_degree + 1)
    p = ca.SX.sym("p", na + 3)
    x1 = ca.SX.sym("x1", 2)
    v = ca.SX.sym("v")
    a = ca.reshape(p[:na], 4, bezier_degree + 1)
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


def _polish(model, opts, alpha, x0, T, tol=1e-12, max_iter=20):
    """Minimum-norm Newton on (alpha, x0, T) for the exact periodic orbit (module doc).

    The Jacobian (forward sensitivities through every RK4 step) is refreshed only when
    the residual contracts by less than 10x (chord steps otherwise)."""
    plain, with_sens = _polish_function(model, opts.bezier_degree, opts.polish_steps)
    res = _periodicity_residual(model, opts.bezier_degree)
    na = 4 * (opts.bezier_degree + 1)
    pv = np.r_[np.asarray(alpha, dtype=float).ravel(order="F"), np.ravel(x0), float(T)]
    hist, Jv = [], None
    for _ in range(max_iter):
        if Jv is None:
            x1, S = (np.array(v) for v in with_sens(pv))
        else:
            x1 = np.array(plain(pv))
        rv, Rp, Rx = (np.array(v) for v in res(pv, x1, opts.speed))
        rv = rv.ravel()
        hist.append(float(np.max(np.abs(rv))))
        if not np.isfinite(hist[-1]) or hist[-1] <= tol \
                or (len(hist) > 3 and hist[-1] < 1e-10 and hist[-1] >= hist[-2]):
            break      # converged, stagnating at round-off, or diverged
        if Jv is not None and hist[-1] > 0.1 * hist[-2]:     # chord step too slow
            S = np.array(with_sens(pv)[1])
            Jv = None
        if Jv is None:
            Jv = Rp + Rx @ S
        pv = pv - np.linalg.lstsq(Jv, rv, rcond=None)[0]
    if not hist[-1] <= max(tol, 1e-10):
        raise GaitOptimizationError(
            f"polish (Newton on the exact periodic orbit) did not converge: residual "
            f"{hist[-1]:.2e} after {len(hist)} iterations; try more n_intervals or "
            f"polish_steps", status="polish_failed")
    a_new = pv[:na].reshape(4, -1, order="F")
    return a_new, pv[na:na + 2], float(pv[na + 2]), hist


def make_solver(prob: Problem, opts: GaitOptions, verbose: bool = False):
    """IPOPT on ``prob`` with exact derivatives: the structured ``hess_lag``, ``jac_g``,
    ``grad_f`` (default) or CasADi's AD of the whole MX graph
    (``opts.derivatives == 'casadi'``, the baseline)."""
    ipopt = {"print_level": 5 if verbose else 0, "tol": 1e-9, "max_iter": 500,
             "mu_strategy": "adaptive", "linear_solver": "mumps", "sb": "yes"}
    ipopt.update(opts.ipopt)
    sopts = {"ipopt": ipopt, "print_time": False, "expand": opts.expand, "error_on_fail": False}
    if opts.derivatives == "structured":
        sopts.update(hess_lag=prob.hess_lag, jac_g=prob.jac_g, grad_f=prob.grad_f)
    return ca.nlpsol("gait_nlp", "ipopt", prob.nlp, sopts)


@dataclass
class CollocationResult:
    """IPOPT's solution of the transcribed problem, before the polish: ``T``, ``alpha``
    (4 x (M+1)), ``Xs`` (2 x (N+1), x at interval starts), ``Xc`` (2 x N d, x at the
    collocation points), ``cost`` (the NLP objective, unscaled), IPOPT's ``status`` and
    ``iterations``, its ``timing`` (seconds per callback), ``build_time``, ``solve_time``."""

    T: float
    alpha: np.ndarray
    Xs: np.ndarray
    Xc: np.ndarray
    cost: float
    status: str
    iterations: int
    timing: dict
    build_time: float
    solve_time: float


def solve_collocation(model, opts: GaitOptions, *, verbose: bool = False,
                      warm_start=None, margins: dict | None = None) -> CollocationResult:
    """Build the NLP (path constraints tightened by ``margins``), run IPOPT from the
    built-in guess (or ``warm_start``, a Gait) and return the raw solution; raises
    :class:`GaitOptimizationError` when IPOPT fails or a constraint family is still
    violated."""
    _check_reachable(opts)
    t0 = time.perf_counter()
    prob = build_problem(model, opts, margins)
    solver = make_solver(prob, opts, verbose)
    t_build = time.perf_counter() - t0
    w0 = initial_guess(model, opts) if warm_start is None else _warm(model, opts, warm_start)
    sol = solver(x0=w0, lbx=prob.lbx, ubx=prob.ubx, lbg=prob.lbg, ubg=prob.ubg)
    stats = solver.stats()
    t_solve = time.perf_counter() - t0 - t_build
    viol = _violations(prob, np.array(sol["g"]).ravel())
    status = stats.get("return_status", "unknown")
    if not stats.get("success", False) or viol:
        raise GaitOptimizationError(
            f"no feasible gait: IPOPT status '{status}' after {stats.get('iter_count', '?')} "
            f"iterations (speed {opts.speed:g} m/s, mu {opts.mu:g}, torque limit "
            f"{opts.torque_limit:g} N m); violated constraint families at the last iterate: "
            f"{describe_violations(viol)}. Try a lower speed, a larger mu or torque_limit, "
            f"wider step_length_bounds, or more IPOPT iterations (option "
            f"ipopt={{'max_iter': ...}}, --max-iter on the command line).",
            status=status, violations=viol)
    T, alpha, Xs, Xc, _ = (np.array(v) for v in prob.unpack(sol["x"]))
    return CollocationResult(
        T=float(T.item()), alpha=alpha, Xs=Xs, Xc=Xc,
        cost=float(sol["f"]) / prob.cost_scale, status=status,
        iterations=int(stats.get("iter_count", -1)),
        timing={k[7:]: float(v) for k, v in stats.items() if k.startswith("t_wall_")},
        build_time=t_build, solve_time=t_solve)


def optimize_gait(model, options: GaitOptions | None = None, *, verbose: bool = False,
                  warm_start=None, max_refinements: int = 3, **overrides):
    """Solve the reference-gait problem of SPEC section 2 and return a :class:`Gait`.

    ``options`` is a :class:`GaitOptions`; keyword ``overrides`` replace single fields
    (``optimize_gait(m, speed=1.0)``).  ``warm_start`` may be a previous :class:`Gait`
    of the same Bezier degree.  Raises :class:`GaitOptimizationError` with IPOPT's status
    and the violated constraint families when no feasible gait is found.

    The path constraints are imposed at the nodes; the polished gait is then checked on
    a dense grid (``Gait.violations``).  Where an active constraint is exceeded between
    the nodes (torque, normal force, friction, clearance), its node bound is tightened
    by twice the excess and the problem solved again from the gait found, at most
    ``max_refinements`` times.  ``solver_stats['dense_grid_violations']`` lists what
    remains (empty for a valid gait), ``solver_stats['refinements']`` the passes.
    """
    from .gait import Gait

    opts = options or GaitOptions()
    if not isinstance(opts, GaitOptions):
        raise ValueError(f"options must be GaitOptions, got {type(opts).__name__}")
    if overrides:
        opts = opts.replace(**overrides)
    t0 = time.perf_counter()
    margins, passes, best = {}, [], None
    for attempt in range(1 + max_refinements):
        try:
            r = solve_collocation(model, opts, verbose=verbose, warm_start=warm_start,
                                  margins=margins)
        except GaitOptimizationError as e:
            if best is None:
                raise
            passes.append(dict(margins=dict(margins), failed=str(e)))
            break                   # keep the previous gait and report its violations
        t_p = time.perf_counter()
        alpha_p, x0_p, T_p, hist = _polish(model, opts, r.alpha, r.Xs[:, 0], r.T)
        t_polish = time.perf_counter() - t_p
        gait = Gait(model, opts, alpha_p, x0_p, T_p)
        # the path constraints hold at the nodes; check between them (dense grid)
        viol = gait.violations()
        passes.append(dict(iterations=r.iterations, margins=dict(margins),
                           violations=[list(v) for v in viol]))
        best = (gait, r, viol, hist, t_polish, (alpha_p, x0_p, T_p))
        fixable = [(_FIXED_BY.get(n, n), v) for n, v in viol if _FIXED_BY.get(n, n) in MARGINS]
        if not fixable or len(fixable) < len(viol) or attempt == max_refinements:
            break
        # tighten the node constraints by twice the excess and solve again from here
        for n, v in fixable:
            margins[n] = margins.get(n, 0.0) + 2 * v + 1e-9
        warm_start = gait
    gait, r, viol, hist, t_polish, (alpha_p, x0_p, T_p) = best
    gait.solver_stats = dict(
        status=r.status, iterations=sum(p.get("iterations", 0) for p in passes),
        build_time=r.build_time, solve_time=r.solve_time, polish_time=t_polish,
        total_time=time.perf_counter() - t0, ipopt_timing=r.timing, ipopt_cost=r.cost,
        polish_residuals=hist,
        polish_change=float(np.max(np.abs(np.r_[(alpha_p - r.alpha).ravel(),
                                                x0_p - r.Xs[:, 0], T_p - r.T]))),
        dense_grid_violations=[list(v) for v in viol])
    if len(passes) > 1:
        gait.solver_stats["refinements"] = passes
    return gait


def _warm(model, opts, gait):
    if gait.alpha.shape != (4, opts.bezier_degree + 1):
        raise ValueError("warm_start gait has another bezier_degree")
    s_start, s_coll = _grid(opts)
    Xs = np.vstack([gait.q(s_start * gait.T)[0], gait.dq(s_start * gait.T)[0]])
    Xc = np.vstack([gait.q(s_coll * gait.T)[0], gait.dq(s_coll * gait.T)[0]])
    return _stack(model, opts, gait.T, gait.alpha, Xs, Xc)
