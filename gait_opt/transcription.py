"""Transcription of the reference-gait problem (docs: theory §2) into an NLP for IPOPT,
with structured exact derivatives.

Transcription.  The actuated joints are Bezier polynomials of s = t / T (so q_a^d,
dq_a^d, ddq_a^d are exact everywhere and continue past T); only the unactuated row of
eq. (1) is an ODE, x = (q_u, dq_u), and it is transcribed by orthogonal collocation
(Legendre by default: order 2d at interval ends, i.e. 6 for d = 3, with the same number
of variables as Radau; Radau is available for comparison, see benchmarks/bench_gait.py).
Path constraints (torques, contact force, friction cone, swing-foot clearance, with
``torso_lean_max`` the torso's lean) are imposed at every interval boundary and
collocation point; knee limits on the Bezier coefficients, which bounds the polynomial
on the whole step (convex hull).

Robots.  Everything is sized by the model: n = nq joints, nu = n - 1 torques (RABBIT:
5 and 4, the numbers quoted below).  Knee limits apply to the joints between leg links
(none for legs of one link).  Legs without knees cannot lift the swing foot
(``model.scuffing_ignored``): the clearance constraint is then z_sw >= clearance
4 s (1 - s) (x_sw - model.scuff_zone) / leg length, which keeps the foot above the
ground beyond the scuff zone in front of the stance foot and lets it graze at most that
far below the ground nearer (as it must, passing the stance leg).

Exact Hessian with structure.  The actuated joints are lifted at every point: variables
QA_k = (q_a, dq_a/ds, d2q_a/ds2) at point k, tied to alpha by linear equalities.  Every
nonlinear term of the NLP is then either a function of one point's
z_k = (x_k, QA_k, T) (2 + 3 nu + 1 = 15 numbers) or of the boundary variables (T, alpha,
x(0), x(1)) of the impact and periodicity conditions.  The constraints and the cost are *linear* in the
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

Speed as a parameter.  ``build_problem(..., speed_parameter=True)`` makes the speed the
NLP's parameter p instead of a constant: it enters only the speed constraint
x_end - p T (whose Hessian does not involve p) and the factor 1/p of the per-length
cost, so one NLP and one solver serve every speed of a family
(:mod:`gait_opt.speed_family`), the derivatives unchanged in structure.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from biped_casadi.caching import cached
from biped_casadi.numerics import ipopt_solver

from .options import GaitOptions, guess_step_length
from .parametrisation import reference_dynamics

__all__ = ["Problem", "build_problem", "initial_guess", "make_solver", "describe_violations",
           "constraint_violations", "warm_start_vector", "torso_lean_bound", "MARGINS",
           "FIXED_BY", "UNITS"]


def _rows(model) -> tuple[dict, int, int]:
    """Rows of a point's output vector (see _point_functions), their number, and the
    size of z_k = (q_u, dq_u, q_a, dq_a/ds, d2q_a/ds2, T): 10 and 15 for RABBIT."""
    nu = model.nu
    rows = dict(f=slice(0, 2), u=slice(2, 2 + nu), Fx=2 + nu, Fz=3 + nu, zsw=4 + nu,
                cost=5 + nu)
    if model.scuffing_ignored:
        rows["xsw"] = 6 + nu
    return rows, 6 + nu + int(model.scuffing_ignored), 3 + 3 * nu

@dataclass
class Problem:
    """The transcribed NLP: ``nlp`` (x, f, g), bounds, the constraint families
    ``groups`` (name, start, stop) in g, ``unpack`` w -> (T, alpha, Xs, Xc, QA), and the
    structured exact derivatives in nlpsol's signatures: ``hess_lag`` (x, p, lam_f,
    lam_g) -> triu(H), ``jac_g`` (x, p) -> (g, dg/dx), ``grad_f`` (x, p) -> (f, df/dx);
    ``speed_parameter``: p is the speed (1 number; else p is empty)."""

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
    speed_parameter: bool = False


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


@cached(maxsize=16)
def _point_functions(model, bezier_degree: int, cost: str):
    """Per-point outputs and their exact Hessian (SX, built once per model and cost).

    ``point(z)`` -> out = (T dq_u, T ddq_u, u (nu), Fx, Fz, z_sw, cost density[, x_sw]),
    with z = (q_u, dq_u, q_a, dq_a/ds, d2q_a/ds2, T): the first two outputs are the
    unactuated row of eq. (1) as an ODE in s; the cost density is u'u (per-length cost,
    times 1/v outside) or T u'u ('torque_squared'); x_sw only for legs without knees.
    ``point_jac(z)`` -> (out, d out / dz); ``point_cost(z)`` -> (cost density, gradient);
    ``point_hess(z, c)`` -> upper triangle of d2(c' out)/dz2 (15x15 for RABBIT).
    """
    ref = reference_dynamics(model, bezier_degree)
    nu = model.nu
    _, n_out, n_z = _rows(model)
    z = ca.SX.sym("z", n_z)
    x, lifted, T = z[0:2], z[2:2 + 3 * nu], z[2 + 3 * nu]
    q = ca.vertcat(x[0], lifted[:nu])
    dq = ca.vertcat(x[1], lifted[nu:2 * nu] / T)
    ddqa = lifted[2 * nu:3 * nu] / T**2
    ddq = ca.vertcat(ref.ddqu(q, dq, ddqa), ddqa)
    u = ref.torque(q, dq, ddq)
    Fx, Fz = model.ground_reaction_acc(q, dq, ddq)
    xsw, zsw = model.swing_foot(q)
    density = ca.sumsqr(u) * (T if cost == "torque_squared" else 1)
    # common subexpression elimination first: the model's expressions repeat a lot
    # (3587 -> 1636 operations), which halves the size of the Hessian below
    extra = [xsw] if model.scuffing_ignored else []
    out = ca.cse(ca.vertcat(T * ca.vertcat(x[1], ddq[0]), u, Fx, Fz, zsw, density, *extra))
    density = out[5 + nu]
    point = ca.Function("point", [z], [out], ["z"], ["out"])
    point_jac = ca.Function("point_jac", [z], [out, ca.jacobian(out, z)], ["z"], ["out", "J"])
    point_cost = ca.Function("point_cost", [z], [density, ca.gradient(density, z)], ["z"],
                             ["density", "grad"])
    c = ca.SX.sym("c", n_out)
    H = ca.triu(ca.hessian(ca.dot(c, out), z)[0])
    point_hess = ca.Function("point_hess", [z, c], [H], ["z", "c"], ["H"])
    return point, point_jac, point_cost, point_hess


def _boundary_function(model, opts: GaitOptions, margins=None):
    """End of step, impact (paper eq. 2-3) and periodicity, as SX of
    v_b = (T, vec(alpha), x(0), x(1)) and the speed v; returns (Function (vb, v),
    Hessian Function (vb, lam), [(name, rows, lo, hi)]).  With a margin of the clearance
    at the ends, the swing foot's slopes there (:func:`_clearance_slopes`)."""
    ref = reference_dynamics(model, opts.bezier_degree)
    M, nu = opts.bezier_degree, model.nu
    vb = ca.SX.sym("vb", 1 + nu * (M + 1) + 4)
    v = ca.SX.sym("v")
    T = vb[0]
    alpha = ca.reshape(vb[1:1 + nu * (M + 1)], nu, M + 1)
    x0, x1 = vb[-4:-2], vb[-2:]
    qa0, dqa0, _ = ref.qa(alpha, 0, T)
    qa1, dqa1, _ = ref.qa(alpha, 1, T)
    q_minus = ca.vertcat(x1[0], qa1)
    dq_minus = ca.vertcat(x1[1], dqa1)
    q_plus, dq_plus, F_imp, _, v_old = model.impact_full(q_minus, dq_minus)
    x_end, z_end = model.swing_foot(q_minus)
    _, dz_end = model.swing_foot_velocity(q_minus, dq_minus)
    mu, inf = opts.impulse_mu, np.inf          # the impulse's own bound (default mu)
    families = [
        ("periodicity (q)", q_plus - ca.vertcat(x0[0], qa0), 0, 0),
        ("periodicity (dq)", dq_plus - ca.vertcat(x0[1], dqa0), 0, 0),
        ("swing foot on ground at T", z_end, 0, 0),
        ("speed", x_end - v * T, 0, 0),
        ("step length", x_end, *opts.step_length_bounds),
        ("strike velocity", dz_end, -inf, -opts.min_strike_speed),
        ("lift-off velocity", v_old[1], opts.min_liftoff_speed, inf),
        ("impact impulse cone", ca.vertcat(F_imp[1], mu * F_imp[1] - F_imp[0],
                                           mu * F_imp[1] + F_imp[0]), 0, inf),
    ]
    if "swing-foot clearance at the ends" in (margins or {}):
        start = (ca.vertcat(x0[0], qa0), ca.vertcat(x0[1], dqa0))
        families.append(_clearance_slopes(model, opts, T, start, (q_minus, dq_minus),
                                          margins["swing-foot clearance at the ends"]))
    g = ca.cse(ca.vertcat(*[f[1] for f in families]))
    lam = ca.SX.sym("lam", g.numel())
    Hb = ca.triu(ca.hessian(ca.dot(lam, g), vb)[0])     # free of v: v T is linear in T
    bnd = ca.Function("boundary", [vb, v], [g, ca.jacobian(g, vb)], ["vb", "v"], ["g", "J"])
    bnd_hess = ca.Function("boundary_hess", [vb, lam], [Hb], ["vb", "lam"], ["H"])
    return bnd, bnd_hess, families


#: path-constraint families that between-node violations can be fixed for, by tightening
#: the node constraints: family -> unit of the margin
MARGINS = {"torque limit": "N m", "normal force": "N", "friction cone": "(ratio)",
           "swing-foot clearance": "m", "torso lean": "rad",
           "swing-foot clearance at the ends": "m"}
#: dense-grid families (Gait.violations) fixed by another family's margin
FIXED_BY = {"swing foot above ground": "swing-foot clearance"}


def _clearance_slopes(model, opts, T, start, end, margin) -> tuple:
    """The clearance bound at s = 0 and 1, where foot and bound are 0: just inside, z_sw >=
    bound needs dz_sw/ds >= its slope 4 clearance (times (x_sw - scuff_zone) / leg length
    for legs without knees) at s = 0, and <= minus that at s = 1."""
    rows = []
    for sign, (q, dq) in ((1, start), (-1, end)):      # m per unit of s, >= margin
        x, dz = model.swing_foot(q)[0], model.swing_foot_velocity(q, dq)[1]
        w = (x - model.scuff_zone) / model.description.leg_length if model.scuffing_ignored else 1
        rows.append(sign * T * dz - 4 * opts.clearance * w)
    return ("swing-foot clearance at the ends", ca.vertcat(*rows), margin, np.inf)


@dataclass
class _Layout:
    """Where everything sits in the decision vector w = (T, alpha, Xs, Xc, QA)."""

    N: int
    d: int
    M: int
    nu: int
    s_all: np.ndarray
    w: ca.MX
    T: ca.MX
    alpha: ca.MX
    Xs: ca.MX
    Xc: ca.MX
    QA: ca.MX
    off_a: int
    off_Xs: int
    off_Xc: int
    off_QA: int

    @property
    def npts(self) -> int:
        return self.s_all.size

    @property
    def nw(self) -> int:
        return self.w.numel()

    @property
    def na(self) -> int:
        return self.nu * (self.M + 1)

    @property
    def n_z(self) -> int:
        return 3 + 3 * self.nu

    def z_index(self) -> np.ndarray:
        """(n_z, npts): positions in w of every point's z_k = (x_k, QA_k, T)."""
        z = np.empty((self.n_z, self.npts), dtype=int)
        nl = 3 * self.nu
        for k in range(self.npts):
            xk = self.off_Xs + 2 * k if k <= self.N else self.off_Xc + 2 * (k - self.N - 1)
            z[:, k] = np.r_[xk, xk + 1, self.off_QA + nl * k + np.arange(nl), 0]
        return z

    def boundary_index(self) -> np.ndarray:
        """Positions in w of the boundary variables (T, vec(alpha), x(0), x(1))."""
        return np.r_[0, self.off_a + np.arange(self.na), self.off_Xs + np.arange(2),
                     self.off_Xs + 2 * self.N + np.arange(2)]


def _layout(opts: GaitOptions, nu: int) -> _Layout:
    M, N, d = opts.bezier_degree, opts.n_intervals, opts.degree
    s_start, s_coll = _grid(opts)
    s_all = np.r_[s_start, s_coll]
    T = ca.MX.sym("T")
    alpha = ca.MX.sym("alpha", nu, M + 1)
    Xs = ca.MX.sym("Xs", 2, N + 1)
    Xc = ca.MX.sym("Xc", 2, N * d)
    QA = ca.MX.sym("QA", 3 * nu, s_all.size)     # (qa, dqa/ds, d2qa/ds2) at every point
    na = nu * (M + 1)
    off_Xs = 1 + na
    off_Xc = off_Xs + 2 * (N + 1)
    return _Layout(N, d, M, nu, s_all, ca.veccat(T, alpha, Xs, Xc, QA), T, alpha, Xs, Xc,
                   QA, 1, off_Xs, off_Xc, off_Xc + 2 * N * d)


class _Constraints:
    """Constraint families appended in order: g, bounds, and (name, start, stop)."""

    def __init__(self):
        self.g, self.lbg, self.ubg, self.groups = [], [], [], []

    def add(self, name, expr, lo, hi):
        expr = ca.vec(expr)
        n = expr.numel()
        start = sum(e.numel() for e in self.g)
        self.g.append(expr)
        self.lbg.append(np.broadcast_to(lo, (n,)).astype(float))
        self.ubg.append(np.broadcast_to(hi, (n,)).astype(float))
        self.groups.append((name, start, start + n))

    @property
    def size(self) -> int:
        return sum(e.numel() for e in self.g)


def _point_constraints(model, opts, lay: _Layout, margins, OUT):
    """Bezier lifting, collocation of the unactuated row and the path constraints, all
    linear in w and in the point outputs OUT: (constraints, QA as a function of alpha)."""
    ref = reference_dynamics(model, opts.bezier_degree)
    rows, _, _ = _rows(model)
    N, d = lay.N, lay.d
    _, C, Dend, _ = _collocation(opts)
    h = 1.0 / N
    s_sym = ca.SX.sym("s")
    a_sx = ca.SX.sym("alpha", lay.nu, lay.M + 1)
    qa_s, dqa_s, ddqa_s = ref.qa(a_sx, s_sym, 1.0)       # with T = 1: s-derivatives
    basis = ca.Function("basis", [a_sx, s_sym], [ca.vertcat(qa_s, dqa_s, ddqa_s)])
    QA_of_alpha = basis.map(lay.npts)(lay.alpha, ca.DM(lay.s_all).T)
    con = _Constraints()
    f_coll = OUT[rows["f"], N + 1:]
    coll, cont = [], []
    for k in range(N):
        Z = ca.horzcat(lay.Xs[:, k], lay.Xc[:, k * d:(k + 1) * d])
        coll.append(ca.mtimes(Z, C) - h * f_coll[:, k * d:(k + 1) * d])
        cont.append(ca.mtimes(Z, Dend) - lay.Xs[:, k + 1])
    con.add("actuated joints (Bezier)", lay.QA - QA_of_alpha, 0, 0)
    con.add("dynamics (collocation)", ca.horzcat(*coll), 0, 0)
    con.add("dynamics (continuity)", ca.horzcat(*cont), 0, 0)
    umax = np.asarray(opts.torque_limit) - margins.get("torque limit", 0.0)
    if umax.ndim:                    # per torque: ca.vec runs down each column (point)
        umax = np.tile(umax, OUT.shape[1])
    mu = opts.mu - margins.get("friction cone", 0.0)
    Fx_all, Fz_all = OUT[rows["Fx"], :], OUT[rows["Fz"], :]
    con.add("torque limit", OUT[rows["u"], :], -umax, umax)
    con.add("normal force", Fz_all, opts.min_normal_force + margins.get("normal force", 0.0),
            np.inf)
    con.add("friction cone", ca.vertcat(mu * Fz_all - Fx_all, mu * Fz_all + Fx_all), 0, np.inf)
    s_all = lay.s_all
    idx = np.flatnonzero((s_all > 1e-9) & (s_all < 1 - 1e-9))
    profile = opts.clearance * 4 * s_all[idx] * (1 - s_all[idx])
    margin = margins.get("swing-foot clearance", 0.0)
    zsw = OUT[rows["zsw"], idx.tolist()]
    if model.scuffing_ignored:      # above the ground in front of the stance foot only
        slope = profile / model.description.leg_length
        con.add("swing-foot clearance", zsw - ca.DM(slope).T * OUT[rows["xsw"], idx.tolist()],
                margin - slope * model.scuff_zone, np.inf)
    else:
        con.add("swing-foot clearance", zsw - ca.DM(profile + margin).T, 0, np.inf)
    if opts.torso_lean_max is not None:
        # q = (q_u, q_a) at every point; the torso's angle is a sum of joint angles, so
        # the rows are linear in w, as build_problem requires
        q_all = ca.vertcat(ca.horzcat(lay.Xs, lay.Xc)[0, :], lay.QA[:lay.nu, :])
        lo, lean, hi = torso_lean_bound(model, q_all, opts.torso_lean_max
                                        - margins.get("torso lean", 0.0))
        con.add("torso lean", lean, lo, hi)
    return con, QA_of_alpha


def torso_lean_bound(model, Q, lean_max: float) -> tuple:
    """The torso-lean constraint of a transcription (walking and running alike).

    Parameters
    ----------
    model : BipedModel
        The robot.
    Q : casadi.MX or casadi.SX
        Joint angles (nq x n), one column per constrained point.
    lean_max : float
        The bound, rad.

    Returns
    -------
    tuple
        (-lean_max, lean, lean_max): ``lean`` the torso's angle less the robot's
        ``torso_upright`` at every column (a column vector), which the constraint keeps
        between the two bounds.
    """
    lean = model.torso_angle.map(Q.shape[1])(Q) - model.description.torso_upright
    return -lean_max, ca.vec(lean), lean_max


def _cost_of_outputs(model, opts, lay: _Layout, OUT, per_speed: bool = True):
    """(1/v) int_0^1 u'u ds (= int u'u dt / step length when x_end = v T), or
    T int_0^1 u'u ds, by the collocation quadrature; scaled by 1e-3 for IPOPT.
    ``per_speed`` False: without the factor 1/v (applied outside, v a parameter)."""
    rows, _, _ = _rows(model)
    _, _, _, Bq = _collocation(opts)
    weights = np.r_[np.zeros(lay.N + 1), np.tile(Bq, lay.N) * (1.0 / lay.N)]
    if opts.cost == "torque_squared_per_length" and per_speed:
        weights = weights / opts.speed
    cost_scale = 1e-3
    return cost_scale * ca.mtimes(OUT[rows["cost"], :], ca.DM(weights)), cost_scale


def _jacobian_and_gradient(model, point_jac, point_cost, lay, z_index, z_all, xw, pw, gfun,
                           A_out, G_w, a_out, bnd, vb_w, speed, factor):
    """Structured constraint Jacobian and objective gradient: d vec(OUT)/dw is block
    sparse (one 10x15 block per point for RABBIT, columns z_index); ``speed`` a number
    or the parameter, ``factor`` (1 or 1/speed) multiplies the objective."""
    npts, nw = lay.npts, lay.nw
    rows, n_out, n_z = _rows(model)
    vb_index = lay.boundary_index()
    sp_j = point_jac.sparsity_out(1)
    rj, cj = (np.array(v) for v in sp_j.get_triplet())
    ks = np.repeat(np.arange(npts), rj.size)
    dout_sp = ca.Sparsity.triplet(n_out * npts, nw, (ks * n_out + np.tile(rj, npts)).tolist(),
                                  z_index[np.tile(cj, npts), ks].tolist())
    out_v, Jp = point_jac.map(npts)(z_all)
    # the map's nonzeros are block after block, column-major within a block; the
    # triplet sparsity orders them column-major globally: permute
    order = np.lexsort(((ks * n_out + np.tile(rj, npts)), z_index[np.tile(cj, npts), ks]))
    dout = ca.MX(dout_sp, Jp.nz[order.tolist()])
    _, Jb = bnd(vb_w, speed)
    select_b = ca.DM(ca.Sparsity.triplet(vb_index.size, nw, list(range(vb_index.size)),
                                         vb_index.tolist()), 1.0)
    g_w = ca.densify(gfun(xw, out_v, pw))
    jac_g = ca.vertcat(G_w + ca.mtimes(A_out, dout), ca.mtimes(Jb, select_b))
    jac_g_fun = ca.Function("jac_g", [xw, pw], [g_w, jac_g], ["x", "p"], ["g", "jac_g_x"])
    # objective: only the cost density of the collocation points (weights a_k)
    wk = np.array(a_out).ravel()[rows["cost"]::n_out]
    cpts = np.flatnonzero(wk)
    dens, dgrad = point_cost.map(cpts.size)(z_all[:, cpts.tolist()])
    f_w = ca.mtimes(dens, ca.DM(wk[cpts]))
    grad_w = ca.densify(ca.mtimes(ca.DM(ca.Sparsity.triplet(
        nw, n_z * cpts.size, z_index[:, cpts].ravel(order="F").tolist(),
        list(range(n_z * cpts.size))), 1.0), ca.vec(dgrad * ca.repmat(ca.DM(wk[cpts]).T, n_z, 1))))
    if factor is not None:
        f_w, grad_w = factor * f_w, factor * grad_w
    grad_f_fun = ca.Function("grad_f", [xw, pw], [f_w, grad_w], ["x", "p"], ["f", "grad_f_x"])
    return jac_g_fun, grad_f_fun


def _hessian_of_lagrangian(model, point_hess, bnd_hess, lay, z_index, z_all, xw, pw, vb_w,
                           A_out, a_out, n_linear, n_g, factor):
    """Exact Hessian of the Lagrangian: per-point 15x15 and boundary Hessians scattered
    into the global upper-triangular sparsity (see the module docstring); ``factor``
    (None or 1/speed) multiplies the objective."""
    npts, nw = lay.npts, lay.nw
    _, n_out, _ = _rows(model)
    vb_index = lay.boundary_index()
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
    lam_g = ca.MX.sym("lam_g", n_g)
    sigma = lam_f if factor is None else lam_f * factor
    c_all = ca.reshape(ca.mtimes(A_out.T, lam_g[:n_linear]) + sigma * a_out, n_out, npts)
    Hp = point_hess.map(npts)(z_all, c_all)
    Hb = bnd_hess(vb_w, lam_g[n_linear:])
    contrib = ca.vertcat(Hp.nz[:], Hb.nz[:])
    H = ca.MX(H_sp, ca.mtimes(scatter, contrib))
    return ca.Function("hess_lag", [xw, pw, lam_f, lam_g], [H],
                       ["x", "p", "lam_f", "lam_g"], ["triu_hess_gamma_x_x"])


def _variable_bounds(model, opts, lay: _Layout):
    """T within its bounds, knee limits on the Bezier coefficients (so on the whole
    polynomial; only where the legs have knees), joint angles within +-pi of the upright
    pose (q = 0 but for a torso hanging below the hip: the hips at +-torso_upright)."""
    lbx = np.full(lay.nw, -np.inf)
    ubx = np.full(lay.nw, np.inf)
    lbx[0], ubx[0] = opts.step_time_bounds
    a_lb = np.full((lay.nu, lay.M + 1), -np.pi)
    a_ub = np.full((lay.nu, lay.M + 1), np.pi)
    up = model.description.upright_q      # a torso hanging below the hip: hips near +-pi
    if any(up):
        a_lb += np.array(up[1:])[:, None]
        a_ub += np.array(up[1:])[:, None]
    for i in model.stance_knees:          # alpha row i - 1 is joint i
        a_ub[i - 1, :] = opts.stance_knee_max
    for i in model.swing_knees:
        a_lb[i - 1, :] = opts.swing_knee_min
    lbx[lay.off_a:lay.off_a + lay.na] = a_lb.ravel(order="F")
    ubx[lay.off_a:lay.off_a + lay.na] = a_ub.ravel(order="F")
    return lbx, ubx


def build_problem(model, opts: GaitOptions, margins: dict | None = None, *,
                  speed_parameter: bool = False) -> Problem:
    """Transcribe the default problem (docs: theory §2) for ``opts`` (see the module docstring).

    Parameters
    ----------
    model : BipedModel
    opts : GaitOptions
    margins : dict, optional
        Family of :data:`MARGINS` -> amount: tightens the path constraints at the nodes,
        so that they hold between the nodes too (see :func:`gait_opt.optimize_gait`).
    speed_parameter : bool
        The speed is the NLP's parameter p (given to the solver at each call;
        ``opts.speed`` unused) instead of a constant.

    Returns
    -------
    Problem
    """
    opts = opts.for_model(model)
    if not np.all(np.isfinite(opts.torque_limit)):
        raise ValueError(f"torque_limit: the robot {model.params.name} has no torque limit "
                         f"(its URDF gives no effort limits) and the gait's |u| <= limit "
                         f"constraint needs one: give it (--torque-limit N, or "
                         f"GaitOptions(torque_limit=N)), or import the URDF with "
                         f"--torque-limit N")
    margins = dict(margins or {})
    unknown = set(margins) - set(MARGINS)
    if unknown:
        raise ValueError(f"margins: unknown constraint families {sorted(unknown)}")
    lay = _layout(opts, model.nu)
    w, npts = lay.w, lay.npts
    _, n_out, n_z = _rows(model)
    OUT = ca.MX.sym("OUT", n_out, npts)
    con, QA_of_alpha = _point_constraints(model, opts, lay, margins, OUT)
    n_linear = con.size
    g_linear = ca.vertcat(*con.g)          # the rows before the boundary (free of p)
    bnd, bnd_hess, families = _boundary_function(model, opts, margins)
    p_nlp = ca.MX.sym("p", int(speed_parameter))
    pw = ca.MX.sym("p", int(speed_parameter))
    speed_nlp, speed_w = (p_nlp, pw) if speed_parameter else (opts.speed, opts.speed)
    per_length = opts.cost == "torque_squared_per_length"
    factor_nlp, factor_w = ((1 / p_nlp, 1 / pw) if speed_parameter and per_length
                            else (None, None))
    g_b, _ = bnd(ca.vertcat(lay.T, ca.vec(lay.alpha), lay.Xs[:, 0], lay.Xs[:, lay.N]),
                 speed_nlp)
    row = 0
    for name, expr, lo, hi in families:
        n = expr.numel()
        con.add(name, g_b[row:row + n], lo, hi)
        row += n
    J_of_out, cost_scale = _cost_of_outputs(model, opts, lay, OUT,
                                            per_speed=not speed_parameter)

    g_of_out = ca.vertcat(*con.g)
    # the point outputs enter g and f linearly, and the other terms of g are linear in w
    # (or the boundary function): constant pull-back maps
    jac = ca.Function("pullback", [w, OUT], [ca.jacobian(g_linear, OUT),
                                             ca.jacobian(g_linear, w),
                                             ca.vec(ca.gradient(J_of_out, OUT))])
    A_out, G_w, a_out = jac(np.zeros(w.numel()), np.zeros(OUT.shape))
    check = jac(np.linspace(-1, 1, w.numel()), np.ones(OUT.shape))
    if any(float(ca.mmax(ca.fabs(a - b))) > 1e-12 for a, b in zip((A_out, G_w, a_out), check)):
        raise AssertionError("internal: constraints must be linear in w and the point outputs")

    point, point_jac, point_cost, point_hess = _point_functions(model, lay.M, opts.cost)
    Z_all = ca.vertcat(ca.horzcat(lay.Xs, lay.Xc), lay.QA, ca.repmat(lay.T, 1, npts))
    out_all = point.map(npts)(Z_all)
    gfun = ca.Function("g_of_out", [w, OUT, p_nlp], [g_of_out])
    ffun = ca.Function("f_of_out", [w, OUT], [J_of_out])
    f_nlp = ffun(w, out_all) if factor_nlp is None else factor_nlp * ffun(w, out_all)
    nlp = {"x": w, "f": f_nlp, "g": gfun(w, out_all, p_nlp)}
    if speed_parameter:
        nlp["p"] = p_nlp

    z_index = lay.z_index()
    xw = ca.MX.sym("x", lay.nw)
    z_all = ca.reshape(xw[z_index.ravel(order="F").tolist()], n_z, npts)
    vb_w = xw[lay.boundary_index().tolist()]
    jac_g_fun, grad_f_fun = _jacobian_and_gradient(model, point_jac, point_cost, lay, z_index,
                                                   z_all, xw, pw, gfun, A_out, G_w, a_out,
                                                   bnd, vb_w, speed_w, factor_w)
    hess_lag = _hessian_of_lagrangian(model, point_hess, bnd_hess, lay, z_index, z_all, xw,
                                      pw, vb_w, A_out, a_out, n_linear, g_of_out.numel(),
                                      factor_w)
    lbx, ubx = _variable_bounds(model, opts, lay)
    unpack = ca.Function("unpack", [w], [lay.T, lay.alpha, lay.Xs, lay.Xc, QA_of_alpha])
    lift = ca.Function("lift", [lay.alpha], [QA_of_alpha])
    return Problem(nlp, lift, lbx, ubx, np.concatenate(con.lbg), np.concatenate(con.ubg),
                   con.groups, unpack, cost_scale, hess_lag, jac_g_fun, grad_f_fun, lay.s_all,
                   speed_parameter)


def guess_step(model, opts: GaitOptions) -> tuple:
    """(step length m, T s) of the built-in guess: :func:`~gait_opt.options.guess_step_length`
    (RABBIT: 0.45 sqrt(speed / 0.75) m; scaled with the leg length, at the same Froude
    number on another robot) kept inside the step-length bounds by a tenth of their
    width, T its time at ``speed`` within the step-time bounds."""
    opts = opts.for_model(model)
    lo, hi = opts.step_length_bounds
    L0 = float(np.clip(guess_step_length(model, opts.speed), lo + 0.1 * (hi - lo),
                       hi - 0.1 * (hi - lo)))
    return L0, float(np.clip(L0 / opts.speed, *opts.step_time_bounds))


def initial_guess(model, opts: GaitOptions):
    """Built-in guess: a double-support pose at impact, feet ``L0`` apart (``L0`` and the
    step time: :func:`guess_step`), the stance leg bent by kappa at its lowest knee and
    the swing leg's link angles the negatives of the stance leg's (so both knees bend the
    human way), the torso leaning 0.05 rad forward from upright (the description's
    ``torso_upright``), joints interpolated linearly in s, the swing leg's knees bending mid-step for clearance (legs without knees: straight
    legs, no bend)."""
    opts = opts.for_model(model)
    M = opts.bezier_degree
    d = model.description
    L0, T0 = guess_step(model, opts)
    kappa, lean = 0.15, 0.05
    # stance links from the foot up at angles a - b_j (b = 0, kappa, kappa, ...); the hip
    # is at x = sum l_j sin(a - b_j) = R sin(a - delta); the swing foot lands at 2 x
    lengths = np.array([link.length for link in reversed(d.leg)])
    bends = np.r_[0.0, np.full(d.k - 1, kappa)]
    P, Q = float(lengths @ np.cos(bends)), float(lengths @ np.sin(bends))
    R, delta = float(np.hypot(P, Q)), float(np.arctan2(Q, P))
    a = delta + float(np.arcsin(np.clip(L0 / (2 * R), -0.95, 0.95)))
    stance = a - bends
    up = d.torso_upright                    # the torso upright (a hanging torso: pi)
    phi = np.r_[stance, lean if up == 0.0 else up + lean, -stance]   # swing leg: hip down
    qT = np.r_[phi[0], np.diff(phi)]
    q0 = model.E @ qT
    qa0, qaT = q0[1:], qT[1:]
    k = np.arange(M + 1) / M
    alpha = qa0[:, None] + k[None, :] * (qaT - qa0)[:, None]
    for i in model.swing_knees:                  # alpha row i - 1 is joint i
        alpha[i - 1] += 0.8 * np.sin(np.pi * k)  # swing knees bend mid-step
        alpha[i - 1] = np.maximum(alpha[i - 1], opts.swing_knee_min + 0.02)
    for i in model.stance_knees:
        alpha[i - 1] = np.minimum(alpha[i - 1], opts.stance_knee_max - 0.02)
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
    "impact impulse cone": "N s", "torso lean": "rad", "swing-foot clearance at the ends": "m"}


def constraint_violations(prob: Problem, gval: np.ndarray, tol: float = 1e-6):
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
    return ipopt_solver("gait_nlp", prob.nlp, sopts)


def warm_start_vector(model, opts, gait):
    """The decision vector of a previous gait (same Bezier degree), to warm-start IPOPT."""
    if not hasattr(gait, "alpha") or not hasattr(gait, "T"):
        raise TypeError(f"warm_start: a Gait is needed, got {type(gait).__name__}")
    if gait.alpha.shape != (model.nu, opts.bezier_degree + 1):
        raise ValueError("warm_start gait has another bezier_degree")
    s_start, s_coll = _grid(opts)
    Xs = np.vstack([gait.q(s_start * gait.T)[0], gait.dq(s_start * gait.T)[0]])
    Xc = np.vstack([gait.q(s_coll * gait.T)[0], gait.dq(s_coll * gait.T)[0]])
    return _stack(model, opts, gait.T, gait.alpha, Xs, Xc)
