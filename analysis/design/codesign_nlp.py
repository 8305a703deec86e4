"""Transcription of the robust co-design (issue 20): perturbation scenarios of the hybrid
zero dynamics walked step by step with the walker's own rule, as smooth NLP functions of
the design (M1, the rejoin time of v_c), the perturbation scale s and, optionally, the
gait (its Bezier coefficients alpha, T and the unactuated start state).

Rule.  Every scenario is multiple shooting with one shooting interval per step: the
step's start (q_u, dq_u, y_i, dy_i) are decision variables, and inside the step the
closed loop of :mod:`biped_casadi.control.zero_dynamics` is integrated by classical RK4
on the fixed grid tau_k = k T / N (N = ``nodes_per_T``), exactly as
:class:`~biped_casadi.simulation.tv_walker.ZeroDynamicsWalker` does, followed by one
partial RK4 step of length eta h (the reference state integrated alongside) that ends on
the strike z_sw = 0.  The number of full nodes of every scenario-step (its *bracket*) is
fixed during one IPOPT solve and re-chosen between solves from eta (the outer loop of
:mod:`analysis.design.codesign`).  With the bracket fixed every function is smooth: the
reference's joins (T, and (1 + c) T for the ramp continuation) lie on grid nodes, so no
RK4 step straddles them, and eta in [0, 1) keeps the partial step inside one node
interval.

Derivatives.  Forward sensitivities: one compiled SX Function per RK4 node gives the
node's next state, its diagnostics (torques, stance reaction, swing foot, eq. 24
denominator) and their Jacobians in the step's columns (its start, M1, the rejoin, and
the gait's variables through the tabulated reference and its own sensitivities); the
partial step, the impact (eq. 2-3), the reset of v_c (eq. 17) and the scenario starts
are SX Functions differentiated by AD.  IPOPT gets the exact constraint Jacobian; the
Hessian is approximated (L-BFGS).  ``tests/test_codesign.py`` checks the Jacobian
against central differences.

Constraints per scenario-step (the walker's validity, :mod:`biped_casadi.simulation.validity`,
with margins): torque, stance normal force, friction cone and the eq. 24 denominator at
every node (aggregated per chunk of nodes by a Kreisselmeier-Steinhauser bound, which
is conservative), the swing foot above the ground at every node before the strike, the
strike (z_sw = 0, moving down, in front of the stance foot), the impact impulse normal
and inside the cone, lift-off of the old stance foot, continuity into the next step.
The gait, when free, carries the constraints of :mod:`gait_opt.transcription` on its own
nominal step (periodic through the impact, on the ground at T, speed, step length,
strike and lift-off speeds, impulse cone, torque, contact, friction, clearance, knee
limits), evaluated on the same reference table.
"""
from __future__ import annotations

import hashlib
import math
import os
import subprocess
import tempfile
import time
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from biped_casadi.caching import cache_dir, cached
from biped_casadi.control.zero_dynamics import zero_dynamics
from biped_casadi.numerics import rk4_step
from biped_casadi.simulation.perturbation import PAPER_SIZES
from gait_opt.parametrisation import reference_dynamics

__all__ = ["TranscriptionSettings", "Transcription", "compiled", "FAMILIES"]

#: the constraint families of a scenario-step, in the user's words
FAMILIES = {
    "torque": "torque limit",
    "normal": "stance normal force",
    "friction": "stance friction cone",
    "denominator": "controller singularity margin (eq. 24)",
    "clearance": "swing foot above the ground",
    "strike": "swing foot on the ground at the strike",
    "strike_speed": "swing foot moving down at the strike",
    "strike_front": "strike in front of the stance foot",
    "impulse_normal": "impact impulse pressing on the ground",
    "impulse_cone": "impact impulse inside the friction cone",
    "liftoff": "old stance foot lifting off",
    "continuity": "continuity through the impact",
    "final_error": "error at the last step",
    "gait": "gait",
}


@dataclass(frozen=True)
class TranscriptionSettings:
    """How scenarios are transcribed and what margins they keep.

    Parameters
    ----------
    nodes_per_T : int
        RK4 nodes per T (the walker's rule; a multiple of 100 keeps the ramp
        continuation's join at 1.03 T on a node).
    horizon : float
        Longest step, fraction of T (nodes are tabulated up to it).
    mu : float
        Friction coefficient of the scenarios' stance foot and impulse (with the margin
        below).
    torque_limit : float
        N m (with the margin below).
    torque_margin : float
        N m kept below the torque limit (peaks between the NLP's nodes).
    mu_margin : float
        Kept below mu in every cone.
    normal_force_min : float
        Lowest stance normal force, fraction of the weight.
    impulse_min : float
        Lowest normal impulse at a strike, N s.
    liftoff_min, strike_speed_min : float
        m/s: the old stance foot's upward speed after an impact, the swing foot's
        downward speed at a strike.
    strike_front_min : float
        m: the strike lands at least this far in front of the stance foot.
    den_margin : float
        The eq. 24 denominator keeps its sign and at least this fraction of its largest
        magnitude on the reference (the walker stops at 0.01).
    clearance_mid : float
        m: swing-foot height kept between 0.1 T and 0.9 T (above 0 elsewhere).
    chunk : int
        Nodes per aggregated constraint.
    ks_rho : float
        Sharpness of the Kreisselmeier-Steinhauser aggregation (normalised units).
    threads : int
        Threads the scenarios of one step are walked on.
    """

    nodes_per_T: int = 100
    horizon: float = 1.6
    mu: float = 0.6
    torque_limit: float = 150.0
    torque_margin: float = 3.0
    mu_margin: float = 0.02
    normal_force_min: float = 0.05
    impulse_min: float = 0.5
    liftoff_min: float = 0.02
    strike_speed_min: float = 0.02
    strike_front_min: float = 0.02
    den_margin: float = 0.03
    clearance_mid: float = 0.001
    chunk: int = 10
    ks_rho: float = 300.0
    threads: int = 2


# ------------------------------------------------------------------ compiled functions
def compiled(f: ca.Function, flags: str = "-O1") -> ca.Function:
    """``f`` compiled to a shared library kept in the cache folder, keyed by its content.

    Parameters
    ----------
    f : casadi.Function
        An SX Function.
    flags : str
        Optimisation flag of the C compiler.

    Returns
    -------
    casadi.Function
        The compiled Function (``casadi.external``), or ``f`` itself when no C compiler
        is available.
    """
    root = cache_dir() / "codesign_so"
    key = hashlib.sha256((f.serialize() + flags + ca.__version__).encode()).hexdigest()[:16]
    so = root / f"{f.name()}_{key}.so"
    if not so.is_file():
        try:
            root.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryDirectory() as tmp:
                c = os.path.join(tmp, f"{f.name()}.c")
                f.generate(f"{f.name()}.c", {"with_header": False})
                os.replace(f"{f.name()}.c", c)
                out = str(so) + f".tmp{os.getpid()}"
                subprocess.run(["gcc", flags, "-fPIC", "-shared", c, "-o", out, "-lm"],
                               check=True, capture_output=True)
                os.replace(out, so)
        except (OSError, subprocess.CalledProcessError):
            return f
    return ca.external(f.name(), str(so))


def _ks(v, rho):
    """Kreisselmeier-Steinhauser upper bound of max(v) along axis 0 and its weights."""
    m = v.max(axis=0)
    e = np.exp(rho * (v - m))
    s = e.sum(axis=0)
    return m + np.log(s) / rho, e / s


@cached(maxsize=4)
def _node_functions(model, nG: int):
    """The RK4 node with forward sensitivities, in the columns of a scenario-step.

    Columns (nc = 2 + 2 nu + nu + 1 + nG): the step's start (q_u, dq_u, y_i, dy_i), M1,
    the rejoin fraction, then nG gait columns (alpha, T, r0) that reach the node through
    the tabulated reference R3 (dR3) and through tau, h (dth).
    """
    zd = zero_dynamics(model)
    nq, nu = model.nq, model.nu
    nc = 2 + 3 * nu + 1 + nG
    x, tau, h = ca.SX.sym("x", 2), ca.SX.sym("tau"), ca.SX.sym("h")
    P, R3 = ca.SX.sym("P", zd.n_par), ca.SX.sym("R3", 9 * nq)
    stage = {0.0: R3[:3 * nq], 0.5: R3[3 * nq:6 * nq], 1.0: R3[6 * nq:]}
    xn = rk4_step(lambda xv, c: zd.rhs(xv, tau + c * h, stage[c], P), x, h)
    q, dq, _, u, Fx, Fz, den = zd.point(xn, tau + h, stage[1.0], P)
    xsw, zsw = model.swing_foot(q)
    out = ca.cse(ca.vertcat(xn, u, Fx, Fz, xsw, zsw, den))
    inp = ca.vertcat(x, tau, h, R3, P)
    J = ca.jacobian(out, inp)
    Jx, Jt, JR, JP = J[:, 0:2], J[:, 2:4], J[:, 4:4 + 9 * nq], J[:, 4 + 9 * nq:]
    S, dth, dP = ca.SX.sym("S", 2, nc), ca.SX.sym("dth", 2, nc), ca.SX.sym("dP", zd.n_par, nc)
    D = ca.mtimes(Jx, S) + ca.mtimes(Jt, dth) + ca.mtimes(JP, dP)
    ins, names = [x, S, tau, h, R3, P, dP, dth], ["x", "S", "tau", "h", "R3", "P", "dP", "dth"]
    if nG:
        dR3 = ca.SX.sym("dR3", 9 * nq, nG)
        D = D + ca.horzcat(ca.SX(out.numel(), nc - nG), ca.mtimes(JR, dR3))
        ins.insert(5, dR3)
        names.insert(5, "dR3")
    D = ca.cse(D)
    f = ca.Function(f"codesign_node_{nG}", ins, [out[:2], D[:2, :], out[2:], D[2:, :]],
                    names, ["x_next", "S_next", "diag", "ddiag"])
    return compiled(f)


@cached(maxsize=4)
def _step_functions(model, degree: int, continuation, shape: str, free: bool):
    """SX Functions of a scenario-step's ends (evaluated in CasADi's VM: few calls).

    ``start(s, M1, R0, d)`` -> (x, y_i, dy_i, z_sw) of the perturbed start of step 1;
    ``diag0(x, R, P)`` -> diagnostics at tau = 0; ``last(x_n, r_n, tau_n, dt, P, alpha,
    T, R0)`` -> the partial RK4 step to the strike (the reference state integrated
    alongside), the strike, the impact and the next step's start; each with its
    Jacobian in the differentiable inputs.
    """
    zd = zero_dynamics(model)
    ref = reference_dynamics(model, degree, continuation, shape)
    nq, nu = model.nq, model.nu
    na = nu * (degree + 1)
    # start of step 1
    s, M1, R0 = ca.SX.sym("s"), ca.SX.sym("M1", nu), ca.SX.sym("R0", 3 * nq)
    d = ca.SX.sym("d", 2 * nq)
    q0 = R0[:nq] + s * PAPER_SIZES[0] * d[:nq]
    dq0 = R0[nq:2 * nq] + s * PAPER_SIZES[1] * d[nq:]
    x0, y0, dy0 = zd.step_start(q0, dq0, R0, M1)
    out = ca.vertcat(x0, y0, dy0, model.swing_foot(q0)[1])
    inp = ca.vertcat(s, M1, R0)
    start = ca.Function("codesign_start", [inp, d], [out, ca.jacobian(out, inp)])
    # diagnostics at a given state
    x, P, R = ca.SX.sym("x", 2), ca.SX.sym("P", zd.n_par), ca.SX.sym("R", 3 * nq)
    tau = ca.SX.sym("tau")
    q, dq, _, u, Fx, Fz, den = zd.point(x, tau, R, P)
    xsw, zsw = model.swing_foot(q)
    dg = ca.vertcat(u, Fx, Fz, xsw, zsw, den)
    inp = ca.vertcat(x, R, P)
    diag0 = ca.Function("codesign_diag0", [inp, tau], [dg, ca.jacobian(dg, inp)])
    # the partial step, the strike and the impact
    xn, rn, tn, dt = ca.SX.sym("x_n", 2), ca.SX.sym("r_n", 2), ca.SX.sym("tau_n"), ca.SX.sym("dt")
    alpha, T = ca.SX.sym("alpha", na), ca.SX.sym("T")
    A = ca.reshape(alpha, nu, degree + 1)

    def reference(t, r):
        qa, dqa, ddqa = ref.qa(A, t / T, T)
        qd, dqd = ca.vertcat(r[0], qa), ca.vertcat(r[1], dqa)
        ddqu = ref.ddqu(qd, dqd, ddqa)
        return ca.vertcat(qd, dqd, ddqu, ddqa), ddqu

    def rhs(z, c):
        t = tn + c * dt
        Rt, a = reference(t, z[2:])
        return ca.vertcat(zd.rhs(z[:2], t, Rt, P), z[3], a)

    ze = rk4_step(rhs, ca.vertcat(xn, rn), dt)
    te = tn + dt
    Re, _ = reference(te, ze[2:])
    q, dq, _, u, Fx, Fz, den = zd.point(ze[:2], te, Re, P)
    xsw, zsw = model.swing_foot(q)
    _, dzsw = model.swing_foot_velocity(q, dq)
    qp, dqp, F, _, vold = model.impact_full(q, dq)
    xp, yp, dyp = zd.step_start(qp, dqp, R0, P[:nu])
    out = ca.cse(ca.vertcat(ze[:2], u, Fx, Fz, xsw, zsw, den, dzsw, F, vold[1], xp, yp, dyp))
    inp = ca.vertcat(xn, rn, tn, dt, P, alpha, T, R0)
    wrt = inp if free else ca.vertcat(xn, rn, tn, dt, P)
    J = ca.jacobian(out, wrt)
    if not free:
        J = ca.horzcat(J, ca.SX(out.numel(), inp.numel() - wrt.numel()))
    last = ca.Function("codesign_last", [inp], [out, J])
    last_value = ca.Function("codesign_last_value", [inp], [out[5 + nu]])
    rows = dict(x=slice(0, 2), u=slice(2, 2 + nu), Fx=2 + nu, Fz=3 + nu, xsw=4 + nu,
                zsw=5 + nu, den=6 + nu, dzsw=7 + nu, F=slice(8 + nu, 10 + nu), vold=10 + nu,
                next=slice(11 + nu, 13 + 3 * nu))
    return start, diag0, last, last_value, rows


@cached(maxsize=4)
def _reference_functions(model, degree: int, continuation, shape: str):
    """The gait's reference table with sensitivities in G = (alpha, T, r0).

    ``step(r, S, s, ds, alpha, T)`` -> one RK4 step of the unactuated row in s = t / T
    with dr/dG; ``point(r, alpha, T, s)`` -> (R = (q^d, dq^d, ddq^d), nominal torques,
    stance reaction and swing foot) and their Jacobians in (r, alpha, T); ``boundary(
    r1, alpha, T, r0)`` -> the impact at T and the periodicity residual with Jacobian.
    """
    ref = reference_dynamics(model, degree, continuation, shape)
    nu = model.nu
    na = nu * (degree + 1)
    nG = na + 3
    r, s, ds, T = ca.SX.sym("r", 2), ca.SX.sym("s"), ca.SX.sym("ds"), ca.SX.sym("T")
    alpha = ca.SX.sym("alpha", na)
    A = ca.reshape(alpha, nu, degree + 1)
    S = ca.SX.sym("S", 2, nG)
    rn, _ = ref.rk4(r, s, ds, A, T)
    J = ca.jacobian(rn, ca.vertcat(r, alpha, T))
    Sn = ca.mtimes(J[:, :2], S) + ca.horzcat(J[:, 2:], ca.SX.zeros(2, 2))
    step = ca.Function("codesign_ref_step", [r, S, s, ds, alpha, T], [rn, Sn])
    q, dq, ddq = ref.full(r, A, s, T)
    u = model.inverse_dynamics(q, dq, ddq)
    Fx, Fz = model.ground_reaction_acc(q, dq, ddq)
    xsw, zsw = model.swing_foot(q)
    out = ca.cse(ca.vertcat(q, dq, ddq, u, Fx, Fz, xsw, zsw))
    inp = ca.vertcat(r, alpha, T)
    point = ca.Function("codesign_ref_point", [inp, s], [out, ca.jacobian(out, inp)])
    # impact at T (paper eq. 2-3) and periodicity, as gait_opt.transcription imposes them
    r1, r0 = ca.SX.sym("r1", 2), ca.SX.sym("r0", 2)
    ref0 = reference_dynamics(model, degree)          # [0, T]: no continuation involved
    qa0, dqa0, _ = ref0.qa(A, 0, T)
    qa1, dqa1, _ = ref0.qa(A, 1, T)
    qm, dqm = ca.vertcat(r1[0], qa1), ca.vertcat(r1[1], dqa1)
    qp, dqp, F, _, vold = model.impact_full(qm, dqm)
    xe, ze = model.swing_foot(qm)
    _, dze = model.swing_foot_velocity(qm, dqm)
    out = ca.cse(ca.vertcat(qp - ca.vertcat(r0[0], qa0), dqp - ca.vertcat(r0[1], dqa0), ze, xe,
                            dze, vold[1], F))
    inp = ca.vertcat(r1, alpha, T, r0)
    boundary = ca.Function("codesign_boundary", [inp], [out, ca.jacobian(out, inp)])
    return step, point, boundary


@cached(maxsize=64)
def _accumulated(node: ca.Function, n: int) -> ca.Function:
    return node.mapaccum(f"{node.name()}_acc{n}", n, [0, 1], [0, 1])


@cached(maxsize=64)
def _chunked(node: ca.Function, n: int, m: int, threads: int) -> ca.Function:
    """n nodes accumulated, mapped over m scenarios (on threads)."""
    acc = _accumulated(node, n)
    return acc.map(m, "thread", threads) if threads > 1 and m > 1 else acc.map(m)


# ------------------------------------------------------------------ the transcription
@dataclass
class _Rows:
    """Constraint rows built by one evaluation: values, bounds, Jacobian triplets."""

    g: list = field(default_factory=list)
    lo: list = field(default_factory=list)
    hi: list = field(default_factory=list)
    rows: list = field(default_factory=list)
    cols: list = field(default_factory=list)
    vals: list = field(default_factory=list)
    names: list = field(default_factory=list)
    n: int = 0

    def add(self, value, jac, cols, lo, hi, name):
        """Rows ``value`` (m,) with dense Jacobian ``jac`` (m, len(cols)) on ``cols``."""
        value = np.atleast_1d(np.asarray(value, float))
        m = value.size
        jac = np.asarray(jac, float).reshape(m, len(cols))
        r = self.n + np.arange(m)
        self.g.append(value)
        self.lo.append(np.broadcast_to(lo, (m,)).astype(float))
        self.hi.append(np.broadcast_to(hi, (m,)).astype(float))
        self.rows.append(np.repeat(r, len(cols)))
        self.cols.append(np.tile(np.asarray(cols, int), m))
        self.vals.append(jac.ravel())
        self.names += [name] * m if isinstance(name, str) else list(name)
        self.n += m

    def stack(self):
        cat = np.concatenate
        return (cat(self.g), cat(self.lo), cat(self.hi), cat(self.rows), cat(self.cols),
                cat(self.vals))


class Transcription:
    """Scenarios of the hybrid zero dynamics as NLP functions (module docstring).

    Decision vector w = (G, M1, rejoin, s, then per scenario and step (q_u, dq_u, y_i,
    dy_i, eta)); G = (alpha, T, r0) only when the gait is free.

    Parameters
    ----------
    model : BipedModel
        The robot.
    gait : Gait
        The gait (fixed) or the gait to start from (free); its options give the Bezier
        degree, the continuation past T and, when free, the gait's own constraints.
    directions : numpy.ndarray
        (K, 2 nq) perturbation directions of the scenarios.
    steps : int
        Steps per scenario.
    free_gait : bool
        Whether alpha, T and r0 are decision variables.
    settings : TranscriptionSettings, optional
        Rule and margins.
    """

    #: nodes per compiled call
    CHUNK = 8

    def __init__(self, model, gait, directions, steps: int, free_gait: bool,
                 settings: TranscriptionSettings | None = None):
        self.model, self.gait = model, gait
        self.st = st = settings or TranscriptionSettings()
        self.dirs = np.atleast_2d(np.asarray(directions, float))
        self.K, self.S = len(self.dirs), int(steps)
        self.free = bool(free_gait)
        o = gait.options
        self.degree, self.cont, self.shape = o.bezier_degree, o.continuation, o.continuation_shape
        nu, nq = model.nu, model.nq
        self.nu, self.nq = nu, nq
        self.na = nu * (self.degree + 1)
        self.nG = self.na + 3 if self.free else 0
        self.nc = 2 + 3 * nu + 1 + self.nG          # columns of a scenario-step
        self.nl = 2 + 2 * nu                          # step start variables
        self.N = st.nodes_per_T
        self.n_max = int(math.ceil(st.horizon * self.N))
        self.threads = int(st.threads)
        self.node = _node_functions(model, self.nG)
        self.start_fn, self.diag0_fn, self.last_fn, self.last_value, self.rows = \
            _step_functions(model, self.degree, self.cont, self.shape, self.free)
        if self.free:
            self.ref_step, self.ref_point, self.boundary = _reference_functions(
                model, self.degree, self.cont, self.shape)
        # layout of w
        self.i_G = np.arange(self.nG)
        self.i_M1 = self.nG + np.arange(nu)
        self.i_rejoin = self.nG + nu
        self.i_s = self.nG + nu + 1
        self.n_design = self.nG + nu + 2
        #: the decision-dependent sign and scale of the eq. 24 denominator (set per solve
        #: from the starting design, as the walker sets them per design)
        self.den_sign, self.den_scale = 1.0, 1.0
        self.mg = float(model.description.total_mass * model.description.gravity)

    # ----------------------------------------------------------------- layout helpers
    def gait_vector(self, gait):
        """G = (vec alpha, T, r0) of a gait (column-major alpha, as CasADi reshapes)."""
        return np.r_[gait.alpha.ravel(order="F"), gait.T, gait.x0]

    def unpack(self, w):
        """(alpha (nu, M+1), T, r0, M1, rejoin, s) of w (the fixed gait's where fixed)."""
        w = np.asarray(w, float)
        if self.free:
            G = w[self.i_G]
            alpha = G[:self.na].reshape(self.nu, self.degree + 1, order="F")
            T, r0 = float(G[self.na]), G[self.na + 1:]
        else:
            alpha, T, r0 = self.gait.alpha, self.gait.T, self.gait.x0
        return alpha, T, r0, w[self.i_M1], float(w[self.i_rejoin]), float(w[self.i_s])

    # ----------------------------------------------------------------- reference table
    def table(self, w):
        """The reference at the half-grid s_i = i / (2N), i = 0..2 n_max + 2: R (15, n),
        dR/dG (15, nG, n), the reference state r (2, n) and dr/dG (2, nG, n), and the
        nominal diagnostics for the gait's own constraints (free gait)."""
        alpha, T, r0, *_ = self.unpack(w)
        n = 2 * (self.n_max + self.CHUNK) + 3
        s = np.arange(n) / (2 * self.N)
        if not self.free:
            key = ("fixed",)
            if getattr(self, "_table_key", None) != key:
                q, dq, ddq = self.gait.evaluate(np.minimum(s * T, self.gait.t_max))
                R = np.vstack([q, dq, ddq])
                self._table = dict(R=R, dR=np.zeros((3 * self.nq, 0, n)), r=R[[0, self.nq]],
                                   dr=np.zeros((2, 0, n)))
                self._table_key = key
            return self._table
        key = tuple(w[self.i_G])
        if getattr(self, "_table_key", None) == key:
            return self._table
        nG = self.nG
        a = w[self.i_G][:self.na]
        acc = _accumulated(self.ref_step, n - 1)
        X, SS = acc(r0, np.hstack([np.zeros((2, self.na + 1)), np.eye(2)]),
                    s[None, :-1], 1.0 / (2 * self.N), a, T)
        r = np.hstack([r0[:, None], np.array(X)])
        dr = np.concatenate([np.hstack([np.zeros((2, self.na + 1)), np.eye(2)])[:, :, None],
                             np.array(SS).reshape(2, n - 1, nG).transpose(0, 2, 1)], axis=2)
        out, J = self.ref_point.map(n)(np.vstack([r, np.repeat(np.r_[a, T][:, None], n, 1)]),
                                       s[None, :])
        out, J = np.array(out), np.array(J).reshape(out.shape[0], n, -1).transpose(0, 2, 1)
        # d out / dG = J_r dr + [J_alpha, J_T, 0]
        dout = np.einsum("oan,agn->ogn", J[:, :2], dr)
        dout[:, :self.na + 1] += J[:, 2:]
        nq = self.nq
        self._table = dict(R=out[:3 * nq], dR=dout[:3 * nq], r=r, dr=dr,
                           nominal=out[3 * nq:], dnominal=dout[3 * nq:])
        self._table_key = key
        return self._table

    def R3(self, tab, k0, n):
        """(R3 (45, n), dR3 (45, nG n)) of nodes k0..k0+n-1."""
        idx = 2 * (k0 + np.arange(n))
        R = tab["R"]
        R3 = np.vstack([R[:, idx], R[:, idx + 1], R[:, idx + 2]])
        if not self.free:
            return R3, None
        dR = tab["dR"]
        dR3 = np.concatenate([dR[:, :, idx], dR[:, :, idx + 1], dR[:, :, idx + 2]], axis=0)
        return R3, dR3.transpose(0, 2, 1).reshape(9 * self.nq, -1)   # 45 x (n nG), node-major

    # ----------------------------------------------------------------- one scenario-step
    def _dP(self, T, rejoin):
        nu, nc = self.nu, self.nc
        dP = np.zeros((3 * nu + 1, nc))
        dP[:nu, 2 + 2 * nu:2 + 3 * nu] = np.eye(nu)                # M1
        dP[nu, 2 + 3 * nu] = T                                       # t_c = rejoin T
        if self.free:
            dP[nu, 2 + 3 * nu + 1 + self.na] = rejoin
        dP[nu + 1:2 * nu + 1, 2:2 + nu] = np.eye(nu)               # y_i
        dP[2 * nu + 1:, 2 + nu:2 + 2 * nu] = np.eye(nu)            # dy_i
        return dP

    def nodes(self, tab, L, n, M1, rejoin, T):
        """Integrate scenario-steps from their start variables over n full nodes.

        The scenarios (rows of L) are walked together, ``CHUNK`` nodes per call, mapped
        over ``threads`` threads.

        Parameters
        ----------
        tab : dict
            The reference table (:meth:`table`).
        L : numpy.ndarray
            (m, nl) step starts (q_u, dq_u, y_i, dy_i).
        n : int
            Full nodes.
        M1 : numpy.ndarray
            (nu,) outputs.
        rejoin, T : float
            Rejoin fraction and step duration.

        Returns
        -------
        tuple
            (X (m, 2, n+1), SS (m, 2, nc, n+1), diag (m, 9, n+1), ddiag (m, 9, nc+1, n+1),
            P (m, n_par), dP): the states, their sensitivities in the step's columns, the
            diagnostics at the nodes (node 0 at tau = 0) with their sensitivities (the last
            column, eta, zero), the step parameters and their sensitivities.
        """
        nu, nc, nq, h = self.nu, self.nc, self.nq, T / self.N
        L = np.atleast_2d(L)
        m = len(L)
        P = np.hstack([np.broadcast_to(M1, (m, nu)), np.full((m, 1), rejoin * T), L[:, 2:]])
        dP = self._dP(T, rejoin)
        S0 = np.zeros((2, nc))
        S0[:, :2] = np.eye(2)
        d0, J0 = self.diag0_fn.map(m)(np.vstack([L[:, :2].T, np.repeat(tab["R"][:, :1], m, 1),
                                                  P.T]), 0.0)
        d0 = np.array(d0).T                                           # (m, 9)
        J0 = np.array(J0).reshape(9, m, -1).transpose(1, 0, 2)        # (m, 9, 2 + 15 + 13)
        dd0 = np.zeros((m, 9, nc + 1))
        dd0[:, :, :nc] = J0[:, :, :2] @ S0 + J0[:, :, 2 + 3 * nq:] @ dP
        if self.free:
            dd0[:, :, nc - self.nG:nc] += J0[:, :, 2:2 + 3 * nq] @ tab["dR"][:, :, 0]
        X = np.zeros((m, 2, n + 1))
        SS = np.zeros((m, 2, nc, n + 1))
        diag = np.zeros((m, 9, n + 1))
        ddiag = np.zeros((m, 9, nc + 1, n + 1))
        X[:, :, 0], SS[:, :, :, 0], diag[:, :, 0], ddiag[:, :, :, 0] = L[:, :2], S0, d0, dd0
        x, S = L[:, :2].T.copy(), np.tile(S0, m)
        C = self.CHUNK
        fn = _chunked(self.node, C, m, self.threads)
        Pm = np.repeat(P.T, C, axis=1) if m == 1 else np.hstack(
            [np.repeat(P[i][:, None], C, 1) for i in range(m)])
        for k0 in range(0, n, C):
            k = k0 + np.arange(C)
            R3, dR3 = self.R3(tab, k0, C)
            dth = np.zeros((2, nc * C))
            if self.free:
                iT = nc - self.nG + self.na
                dth[0, np.arange(C) * nc + iT] = k / self.N
                dth[1, np.arange(C) * nc + iT] = 1.0 / self.N
            args = [x, S, (k * h)[None, :], np.full((1, C), h), R3] + (
                [dR3] if self.free else []) + [Pm, np.tile(dP, C), dth]
            Xn, Sn, Dg, DD = (np.array(v) for v in fn(*args))
            cnt = min(C, n - k0)
            sl = slice(k0 + 1, k0 + 1 + cnt)
            X[:, :, sl] = Xn.reshape(2, m, C).transpose(1, 0, 2)[:, :, :cnt]
            SS[:, :, :, sl] = Sn.reshape(2, m, C, nc).transpose(1, 0, 3, 2)[..., :cnt]
            diag[:, :, sl] = Dg.reshape(9, m, C).transpose(1, 0, 2)[:, :, :cnt]
            ddiag[:, :, :nc, sl] = DD.reshape(9, m, C, nc).transpose(1, 0, 3, 2)[..., :cnt]
            x = Xn.reshape(2, m, C)[:, :, -1]
            S = Sn.reshape(2, m, C, nc)[:, :, -1, :].transpose(0, 1, 2).reshape(2, m * nc)
        return X, SS, diag, ddiag, P, dP

    def _last_input(self, tab, x, n, eta, P, T, alpha):
        return np.r_[x, tab["r"][:, 2 * n], n * T / self.N, eta * T / self.N, P,
                     np.asarray(alpha).ravel(order="F"), T, tab["R"][:, 0]]

    def finish(self, tab, x, S, n, eta, P, dP, T, alpha):
        """The partial step of length eta h from node n, the strike, the impact and the
        next step's start: (outputs, Jacobian in the step's columns and eta)."""
        nc, h = self.nc, T / self.N
        out, J = self.last_fn(self._last_input(tab, x, n, eta, P, T, alpha))
        out, J = np.array(out).ravel(), np.array(J)
        m = 2 + 2 + 1 + 1 + P.size + self.na + 1 + 3 * self.nq
        Din = np.zeros((m, nc + 1))
        Din[0:2, :nc] = S
        Din[5, nc] = h
        o = 6
        Din[o:o + P.size, :nc] = dP
        o += P.size
        if self.free:
            g0 = nc - self.nG
            Din[2:4, g0:nc] = tab["dr"][:, :, 2 * n]
            Din[4, g0 + self.na] = n / self.N
            Din[5, g0 + self.na] = eta / self.N
            Din[o:o + self.na, g0:g0 + self.na] = np.eye(self.na)
            Din[o + self.na, g0 + self.na] = 1.0
            Din[o + self.na + 1:, g0:nc] = tab["dR"][:, :, 0]
        return out, J @ Din

    def _with_last(self, diag, ddiag, out, Jl):
        r = self.rows
        ide = np.r_[np.arange(r["u"].start, r["u"].stop), r["Fx"], r["Fz"], r["xsw"], r["zsw"],
                    r["den"]]
        return (np.hstack([diag, out[ide][:, None]]),
                np.concatenate([ddiag, Jl[ide][:, :, None]], axis=2), out, Jl)

    def strike_in(self, tab, X, diag, n_full, P, T, alpha):
        """The bracket and eta of the first strike (None when there is none): the swing
        foot crossing the ground downward in front of the stance foot between two nodes,
        then the root of z_sw in the partial step (safeguarded secant)."""
        z, xs = diag[self.nu + 3, :n_full + 1], diag[self.nu + 2, :n_full + 1]
        cross = np.flatnonzero((z[:-1] >= 0) & (z[1:] < 0) & (xs[1:] > 0))
        cross = cross[cross >= 1]
        if not cross.size:
            return None
        n = int(cross[0])
        a, b, za, zb = 0.0, 1.0, z[n], z[n + 1]
        eta = a - za * (b - a) / (zb - za)
        for _ in range(40):
            ze = float(self.last_value(self._last_input(tab, X[:, n], n, eta, P, T, alpha)))
            if abs(ze) < 1e-14:
                break
            if ze > 0:
                a, za = eta, ze
            else:
                b, zb = eta, ze
            eta_n = a - za * (b - a) / (zb - za)
            if not a < eta_n < b:
                eta_n = 0.5 * (a + b)
            if abs(eta_n - eta) < 1e-15:
                break
            eta = eta_n
        return n, eta

    def _gait_rows(self, rows, w, tab):
        """The gait's own constraints (gait_opt.transcription), on its nominal step."""
        o = self.gait.options
        nq, nu, na = self.nq, self.nu, self.na
        alpha, T, r0, *_ = self.unpack(w)
        n1 = 2 * self.N
        r1, dr1 = tab["r"][:, n1], tab["dr"][:, :, n1]
        out, J = self.boundary(np.r_[r1, w[self.i_G][:na], T, r0])
        out, J = np.array(out).ravel(), np.array(J)
        dG = J[:, :2] @ dr1
        dG[:, :na + 1] += J[:, 2:3 + na]
        dG[:, na + 1:] += J[:, 3 + na:]
        G = self.i_G
        rows.add(out[:2 * nq], dG[:2 * nq], G, 0.0, 0.0, "gait periodicity")
        rows.add(out[2 * nq], dG[2 * nq], G, 0.0, 0.0, "gait swing foot on the ground at T")
        xe, dxe = out[2 * nq + 1], dG[2 * nq + 1]
        dT = np.zeros(self.nG)
        dT[na] = 1.0
        rows.add(xe - o.speed * T, dxe - o.speed * dT, G, 0.0, 0.0, "gait speed")
        rows.add(xe, dxe, G, *o.step_length_bounds, "gait step length")
        rows.add(out[2 * nq + 2], dG[2 * nq + 2], G, -np.inf, -o.min_strike_speed,
                 "gait strike velocity")
        rows.add(out[2 * nq + 3], dG[2 * nq + 3], G, o.min_liftoff_speed, np.inf,
                 "gait lift-off velocity")
        F, dF = out[2 * nq + 4:], dG[2 * nq + 4:]
        mu_i = o.impulse_mu
        rows.add(np.r_[F[1], mu_i * F[1] - F[0], mu_i * F[1] + F[0]],
                 np.vstack([dF[1], mu_i * dF[1] - dF[0], mu_i * dF[1] + dF[0]]), G, 0.0, np.inf,
                 "gait impact impulse cone")
        # path on the nominal step, at the grid nodes inside (0, T)
        idx = 2 * np.arange(1, self.N)
        nom, dnom = tab["nominal"][:, idx], tab["dnominal"][:, :, idx]
        s = idx / (2 * self.N)
        U = o.torque_limit or self.st.torque_limit
        u, du = nom[:nu], dnom[:nu]
        rows.add(u.T.ravel(), du.transpose(2, 0, 1).reshape(-1, self.nG), G, -U, U,
                 "gait torque limit")
        Fx, Fz, dFx, dFz = nom[nu], nom[nu + 1], dnom[nu], dnom[nu + 1]
        rows.add(Fz, dFz.T, G, o.min_normal_force, np.inf, "gait normal force")
        rows.add(np.r_[o.mu * Fz - Fx, o.mu * Fz + Fx], np.vstack([(o.mu * dFz - dFx).T,
                                                                  (o.mu * dFz + dFx).T]),
                 G, 0.0, np.inf, "gait friction cone")
        zsw, dzsw = nom[nu + 3], dnom[nu + 3]
        rows.add(zsw - o.clearance * 4 * s * (1 - s), dzsw.T, G, 0.0, np.inf,
                 "gait swing-foot clearance")

    # ----------------------------------------------------------------- bounds, start
    def bounds(self, M1_box: float = 40.0):
        """Bounds of the design: the gait's (T, knee limits), M1 box, rejoin, s."""
        lb, ub = np.full(self.n_design, -np.inf), np.full(self.n_design, np.inf)
        if self.free:
            o = self.gait.options
            a_lb = np.full((self.nu, self.degree + 1), -np.pi)
            a_ub = np.full((self.nu, self.degree + 1), np.pi)
            for i in self.model.stance_knees:
                a_ub[i - 1, :] = o.stance_knee_max
            for i in self.model.swing_knees:
                a_lb[i - 1, :] = o.swing_knee_min
            lb[:self.na], ub[:self.na] = a_lb.ravel(order="F"), a_ub.ravel(order="F")
            lb[self.na], ub[self.na] = o.step_time_bounds
        lb[self.i_M1], ub[self.i_M1] = -M1_box, M1_box
        lb[self.i_rejoin], ub[self.i_rejoin] = 0.5, 0.75
        lb[self.i_s], ub[self.i_s] = 0.0, 3.0
        return lb, ub


class _Dense:
    """Constraint rows with a dense Jacobian in the design (the reduced NLP)."""

    def __init__(self, nd):
        self.nd, self.g, self.J, self.lo, self.hi, self.names = nd, [], [], [], [], []

    def add(self, value, jac, lo, hi, name):
        value = np.atleast_1d(np.asarray(value, float))
        m = value.size
        self.g.append(value)
        self.J.append(np.asarray(jac, float).reshape(m, self.nd))
        self.lo.append(np.broadcast_to(lo, (m,)).astype(float))
        self.hi.append(np.broadcast_to(hi, (m,)).astype(float))
        self.names += [name] * m if isinstance(name, str) else list(name)

    def ks(self, v, dv, rho, name):
        """One row bounding max(v) <= 0 (KS); v (m, p), dv (m, nd, p)."""
        flat = np.asarray(v).reshape(-1)
        dflat = np.moveaxis(dv, 1, -1).reshape(-1, self.nd)
        val, wts = _ks(flat[:, None], rho)
        self.add(val[0], wts[:, 0] @ dflat, -np.inf, 0.0, name)

    def stack(self):
        return (np.concatenate(self.g), np.vstack(self.J), np.concatenate(self.lo),
                np.concatenate(self.hi))


class Reduced:
    """The co-design NLP in the design variables only (single shooting per scenario).

    Every evaluation walks every scenario with the walker's rule from the design (the
    strike of every step found as the walker finds it), so each iterate is a closed-loop
    trajectory and the strike times are implicit functions of the design; the exact
    Jacobian is condensed from the per-step sensitivities of :class:`Transcription`
    (implicit-function theorem for the strike time).  Decision vector d = (G, M1,
    rejoin, s), G = (alpha, T, r0) when the gait is free.

    Parameters
    ----------
    tr : Transcription
        The scenarios and their rule (its brackets are not used).
    """

    #: pad of a step's tabulated nodes past the previous bracket
    PAD = 6

    def __init__(self, tr: Transcription):
        self.tr = tr
        self.nd = tr.n_design
        self.bracket_guess = np.full((tr.K, tr.S), int(1.05 * tr.N))
        self._last = None
        self.s_weight = 1.0
        self.weights = np.zeros(tr.S)
        #: per scenario: its fixed scale (NaN: the variable s), its steps (at most tr.S),
        #: its error bound (inf: none) and the first step it applies to (0-based; the
        #: bound holds from there to the scenario's last step; default: the last step)
        self.scales = np.full(tr.K, np.nan)
        self.steps = np.full(tr.K, tr.S)
        self.tols = np.full(tr.K, np.inf)
        self.tol_from = np.full(tr.K, tr.S - 1)
        #: (callable M1 -> ((tr A^z, its gradient), (det A^z, its gradient)), bound) or None
        self.jury = None
        self.failures = []
        self.evaluations = 0

    def columns(self, TL):
        """(nc, nd): a scenario-step's columns as functions of the design."""
        tr = self.tr
        C = np.zeros((tr.nc, self.nd))
        C[:tr.nl] = TL
        C[tr.nl:tr.nl + tr.nu, tr.i_M1] = np.eye(tr.nu)
        C[tr.nl + tr.nu, tr.i_rejoin] = 1.0
        if tr.free:
            C[tr.nc - tr.nG:, tr.i_G] = np.eye(tr.nG)
        return C

    def evaluate(self, d):
        """(f, grad f, g, dg/dd, lo, hi) at the design d (cached for the last d)."""
        d = np.asarray(d, float)
        if self._last is not None and np.array_equal(self._last[0], d):
            return self._last[1]
        self.evaluations += 1
        try:
            res = self._evaluate(d)
        except _NoStrike:
            res = None
        if res is None:
            ng = self._ng if hasattr(self, "_ng") else 1
            nan = np.full(ng, np.nan)
            res = (np.nan, np.full(self.nd, np.nan), nan, np.full((ng, self.nd), np.nan),
                   self._lo if hasattr(self, "_lo") else nan,
                   self._hi if hasattr(self, "_hi") else nan)
        self._last = (d.copy(), res)
        return res

    def _evaluate(self, d):
        tr, st = self.tr, self.tr.st
        nu, nc, nd, nl = tr.nu, tr.nc, self.nd, tr.nl
        alpha, T, r0, M1, rejoin, s = tr.unpack(d)
        tab = tr.table(d)
        rows = _Dense(nd)
        f, grad = -self.s_weight * s, np.zeros(nd)
        grad[tr.i_s] = -self.s_weight
        U = st.torque_limit - st.torque_margin
        mu, mg, rho = st.mu - st.mu_margin, tr.mg, st.ks_rho
        rT = tab["r"][:, 2 * tr.N]
        drT = np.zeros((2, nd))
        if tr.free:
            drT[:, tr.i_G] = tab["dr"][:, :, 2 * tr.N]
        dR0 = np.zeros((3 * tr.nq, nd))
        if tr.free:
            dR0[:, tr.i_G] = tab["dR"][:, :, 0]
        n_chunks = int(math.ceil((tr.n_max + 2) / st.chunk))
        t_nodes = np.arange(tr.n_max + 2) / tr.N
        info = []
        Ls, TLs = [], []
        for k in range(tr.K):
            sk = s if not np.isfinite(self.scales[k]) else float(self.scales[k])
            so, sJ = tr.start_fn(np.r_[sk, M1, tab["R"][:, 0]], tr.dirs[k])
            so, sJ = np.array(so).ravel(), np.array(sJ)
            TL = np.zeros((nl, nd))
            if not np.isfinite(self.scales[k]):
                TL[:, tr.i_s] = sJ[:nl, 0]
            TL[:, tr.i_M1] = sJ[:nl, 1:1 + nu]
            TL += sJ[:nl, 1 + nu:] @ dR0
            Ls.append(so[:nl])
            TLs.append(TL)
        for j in range(int(self.steps.max())):
            act = [k for k in range(tr.K) if self.steps[k] > j]
            n_try = min(max(int(self.bracket_guess[k, j]) for k in act) + self.PAD,
                        tr.n_max - 1)
            while True:
                XA, SSA, diagA, ddiagA, PA, dP = tr.nodes(tab, np.array([Ls[k] for k in act]),
                                                          n_try, M1, rejoin, T)
                hits = [tr.strike_in(tab, XA[i], diagA[i], n_try, PA[i], T, alpha)
                        for i in range(len(act))]
                if all(h is not None for h in hits) or n_try >= tr.n_max - 1:
                    break
                n_try = min(n_try + 32, tr.n_max - 1)
            for i, k in enumerate(act):
                tag = f"k{k} j{j}"
                if hits[i] is None:
                    self.failures.append((k, j, "no strike"))
                    raise _NoStrike(tag)
                X, SS, diag, ddiag, P = XA[i], SSA[i], diagA[i], ddiagA[i], PA[i]
                TL = TLs[k]
                n, eta = hits[i]
                self.bracket_guess[k, j] = n
                out, Jl = tr.finish(tab, X[:, n], SS[:, :, n], n, eta, P, dP, T, alpha)
                diag, ddiag, out, Jl = tr._with_last(diag[:, :n + 1], ddiag[:, :, :n + 1],
                                                     out, Jl)
                C = self.columns(TL)
                r = tr.rows
                dz = Jl[r["zsw"]]
                deta = -(dz[:nc] @ C) / dz[nc]                     # implicit function
                Ctot = np.vstack([C, deta[None]])                  # (nc + 1, nd)
                D = lambda J_: J_ @ Ctot                           # noqa: E731
                dd = np.einsum("mcp,cd->mdp", ddiag, Ctot)         # (9, nd, p)
                u, Fx, Fz, zsw, den = diag[:nu], diag[nu], diag[nu + 1], diag[nu + 3], diag[nu + 4]
                du, dFx, dFz, dzsw, dden = (dd[:nu], dd[nu], dd[nu + 1], dd[nu + 3], dd[nu + 4])
                npts = diag.shape[1]
                for c in range(n_chunks):
                    sl = slice(min(c * st.chunk, npts - 1), min((c + 1) * st.chunk, npts))
                    if c * st.chunk >= npts:
                        sl = slice(npts - 1, npts)          # past the strike: the last point
                    where = f"{tag} chunk {c}"
                    v = np.vstack([u[:, sl] / U - 1, -u[:, sl] / U - 1])
                    dv = np.concatenate([du[:, :, sl] / U, -du[:, :, sl] / U])
                    rows.ks(v, dv, rho, "torque " + where)
                    rows.ks(((st.normal_force_min * mg - Fz[sl]) / mg)[None],
                            (-dFz[:, sl] / mg)[None], rho, "normal " + where)
                    v = np.vstack([Fx[sl] - mu * Fz[sl], -Fx[sl] - mu * Fz[sl]]) / mg
                    dv = np.stack([dFx[:, sl] - mu * dFz[:, sl],
                                   -dFx[:, sl] - mu * dFz[:, sl]]) / mg
                    rows.ks(v, dv, rho, "friction " + where)
                    sc = tr.den_sign / tr.den_scale
                    rows.ks((st.den_margin - sc * den[sl])[None], (-sc * dden[:, sl])[None],
                            rho, "denominator " + where)
                # the swing foot lifts at the start and stays clear mid-step
                tn = t_nodes[:n + 1]
                lift = np.flatnonzero((tn > 0) & (tn < 0.1))
                mid = np.flatnonzero((tn >= 0.1) & (tn <= 0.9))
                vref = 0.3 * tn[lift]          # m per unit of s: a lift-off speed scale
                rows.ks((-zsw[lift] / vref)[None], (-dzsw[:, lift] / vref)[None], rho,
                        f"clearance {tag} lift-off")
                rows.ks(((st.clearance_mid - zsw[mid]) / 0.05)[None],
                        (-dzsw[:, mid] / 0.05)[None], rho, f"clearance {tag} mid-step")
                rows.add(out[r["dzsw"]], D(Jl[r["dzsw"]]), -np.inf, -st.strike_speed_min,
                         f"strike_speed {tag}")
                rows.add(out[r["xsw"]], D(Jl[r["xsw"]]), st.strike_front_min, np.inf,
                         f"strike_front {tag}")
                F, dF = out[r["F"]], D(Jl[r["F"]])
                rows.add(F[1], dF[1], st.impulse_min, np.inf, f"impulse_normal {tag}")
                rows.add(np.r_[mu * F[1] - F[0], mu * F[1] + F[0]],
                         np.vstack([mu * dF[1] - dF[0], mu * dF[1] + dF[0]]), 0.0, np.inf,
                         f"impulse_cone {tag}")
                rows.add(out[r["vold"]], D(Jl[r["vold"]]), st.liftoff_min, np.inf,
                         f"liftoff {tag}")
                err = out[r["x"]] - rT
                derr = D(Jl[r["x"]]) - drT
                wj = self.weights[j]
                if wj:
                    f += wj * float(err @ err)
                    grad += 2 * wj * err @ derr
                if j >= min(self.tol_from[k], self.steps[k] - 1):
                    tol = self.tols[k]
                    if np.isfinite(tol):
                        rows.add(err, derr, -tol, tol, f"final_error {tag}")
                info.append(dict(k=k, j=j, err=err.copy(), te=(n + eta) * T / tr.N,
                                 peak_u=float(np.abs(u).max()), impulse=F.tolist()))
                Ls[k] = out[r["next"]]
                TLs[k] = D(Jl[r["next"]])
        if self.jury is not None:
            fn, lam = self.jury
            (trA, dtr), (det, ddet) = fn(M1)
            rows.add(np.r_[det - lam**2, -det - lam**2],
                     np.vstack([_on(nd, tr.i_M1, ddet), _on(nd, tr.i_M1, -ddet)]),
                     -np.inf, 0.0, "jury det")
            rows.add(np.r_[trA - lam - det / lam, -trA - lam - det / lam],
                     np.vstack([_on(nd, tr.i_M1, dtr - ddet / lam),
                                _on(nd, tr.i_M1, -dtr - ddet / lam)]),
                     -np.inf, 0.0, "jury trace")
        if tr.free:
            w_rows = _Rows()
            tr._gait_rows(w_rows, d, tab)
            gv, lo, hi, ri, ci, vals = w_rows.stack()
            Jg = np.zeros((gv.size, nd))
            np.add.at(Jg, (ri, ci), vals)
            rows.add(gv, Jg, lo, hi, w_rows.names)
        self.info = info
        g, J, lo, hi = rows.stack()
        self.names = rows.names
        self._ng, self._lo, self._hi = g.size, lo, hi
        return f, grad, g, J, lo, hi

    def bounds(self, M1_box: float = 40.0):
        """Bounds of the design vector (those of :meth:`Transcription.bounds`)."""
        return self.tr.bounds(M1_box)


class _NoStrike(Exception):
    """A scenario's step found no strike within the horizon."""


def _on(nd, idx, v):
    out = np.zeros(nd)
    out[idx] = np.asarray(v, float).ravel()
    return out


# ------------------------------------------------------------------ IPOPT
class _Oracle(ca.Callback):
    """f, g (with their Jacobians on request) or (f, grad f) / (g, dg) of a
    :class:`Reduced`, for IPOPT through CasADi."""

    def __init__(self, name, nlp, kind, sp, opts=None):
        ca.Callback.__init__(self)
        self.nlp, self.kind, self.sp = nlp, kind, sp
        self.nd, self.ng = nlp.nd, sp.size1()
        self.construct(name, opts or {})

    def get_n_in(self):
        return 1 if self.kind in ("f", "g") else 2

    def get_n_out(self):
        return 1 if self.kind in ("f", "g", "df", "dg") else 2

    def get_sparsity_in(self, i):
        if i == 0:
            return ca.Sparsity.dense(self.nd, 1)
        if self.kind in ("df", "dg"):
            return ca.Sparsity.dense(1, 1) if self.kind == "df" else ca.Sparsity.dense(self.ng, 1)
        return ca.Sparsity(0, 1)

    def get_sparsity_out(self, i):
        k = self.kind
        if k == "f" or (k == "grad_f" and i == 0):
            return ca.Sparsity.dense(1, 1)
        if k in ("grad_f", "df"):
            return ca.Sparsity.dense(1, self.nd)
        if k == "g" or (k == "jac_g" and i == 0):
            return ca.Sparsity.dense(self.ng, 1)
        return self.sp

    def has_jacobian(self):
        return self.kind in ("f", "g")

    def get_jacobian(self, name, inames, onames, opts):
        self._jac = _Oracle(name, self.nlp, "df" if self.kind == "f" else "dg", self.sp, opts)
        return self._jac

    def eval(self, arg):
        f, grad, g, J, _, _ = self.nlp.evaluate(np.array(arg[0]).ravel())
        k = self.kind
        if k == "f":
            return [f]
        if k == "g":
            return [g]
        if k == "df":
            return [grad[None, :]]
        if k == "grad_f":
            return [f, grad[None, :]]
        Jd = ca.DM(J)
        return [Jd] if k == "dg" else [g, Jd]


@dataclass
class NLPSolve:
    """One IPOPT solve of the reduced co-design NLP.

    Parameters
    ----------
    d : numpy.ndarray
        The design at IPOPT's last iterate.
    lam_g : numpy.ndarray
        The constraints' multipliers there.
    status : str
        IPOPT's return status.
    success : bool
        IPOPT's own success flag.
    iterations : int
        IPOPT iterations.
    time : float
        Wall time, s.
    evaluations : int
        Walks of every scenario (evaluations of the constraints).
    """

    d: np.ndarray
    lam_g: np.ndarray
    status: str
    success: bool
    iterations: int
    time: float
    evaluations: int


def solve_nlp(nlp: "Reduced", d0, lb, ub, ipopt: dict | None = None) -> NLPSolve:
    """IPOPT (L-BFGS Hessian, exact constraint Jacobian) on the reduced NLP from d0.

    Parameters
    ----------
    nlp : Reduced
        The NLP functions.
    d0 : array_like
        Starting design.
    lb, ub : array_like
        Bounds of the design.
    ipopt : dict, optional
        Extra IPOPT options.

    Returns
    -------
    NLPSolve
    """
    d0 = np.asarray(d0, float)
    _, _, g0, _, lo, hi = nlp.evaluate(d0)
    if not np.all(np.isfinite(g0)):
        raise ValueError("codesign: a scenario does not strike from the starting design")
    sp = ca.Sparsity.dense(g0.size, nlp.nd)
    cbs = [_Oracle("codesign_f", nlp, "f", sp), _Oracle("codesign_g", nlp, "g", sp),
           _Oracle("codesign_grad_f", nlp, "grad_f", sp), _Oracle("codesign_jac_g", nlp, "jac_g", sp)]
    x = ca.MX.sym("x", nlp.nd)
    opts = {"print_level": 0, "hessian_approximation": "limited-memory", "max_iter": 100,
            "tol": 1e-6, "acceptable_tol": 1e-4, "acceptable_iter": 5,
            "mu_strategy": "adaptive", "bound_push": 1e-8, "bound_frac": 1e-8,
            "linear_solver": "mumps", "sb": "yes"}
    opts.update(ipopt or {})
    solver = ca.nlpsol("codesign", "ipopt", {"x": x, "f": cbs[0](x), "g": cbs[1](x)},
                       {"ipopt": opts, "grad_f": cbs[2], "jac_g": cbs[3], "print_time": False,
                        "error_on_fail": False})
    n0 = nlp.evaluations
    t0 = time.perf_counter()
    sol = solver(x0=d0, lbx=lb, ubx=ub, lbg=lo, ubg=hi)
    st = solver.stats()
    return NLPSolve(d=np.array(sol["x"]).ravel(), lam_g=np.array(sol["lam_g"]).ravel(),
                    status=str(st.get("return_status", "unknown")),
                    success=bool(st.get("success", False)),
                    iterations=int(st.get("iter_count", -1)),
                    time=time.perf_counter() - t0, evaluations=nlp.evaluations - n0)
