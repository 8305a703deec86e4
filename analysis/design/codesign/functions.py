"""The compiled functions of the co-design NLP: one RK4 node of the closed-loop zero
dynamics with its sensitivities, the step's start, partial step and impact, the gait's
reference (the module docstring of :mod:`analysis.design.codesign.transcription`)."""
from __future__ import annotations

from dataclasses import dataclass, replace

import casadi as ca
import numpy as np

from biped_casadi.caching import cached
from biped_casadi.control.zero_dynamics import zero_dynamics
from biped_casadi.numerics import as_number
from biped_casadi.numerics import compiled as _compiled
from biped_casadi.numerics import rk4_step
from biped_casadi.simd import kernels
from biped_casadi.simulation.perturbation import PAPER_SIZES
from gait_opt.parametrisation import reference_dynamics

from .scales import physical_scales

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


#: the co-design's length-valued margins on RABBIT's legs (0.8 m), m, each scaled with the
#: robot's leg length (:meth:`TranscriptionSettings.for_model`): the mid-step clearance
#: row's unit, the mid-step clearance, the strike's distance in front of the stance foot
#: and the lift-off row's height per unit of tau / T
CLEARANCE_SCALE = 0.05
CLEARANCE_MID = 0.001
STRIKE_FRONT_MIN = 0.02
LIFT_SCALE = 0.3
#: the co-design's other RABBIT-sized margins, each scaled with the robot by its kind
#: (:func:`~analysis.design.codesign.scales.physical_scales`): the old stance foot's
#: upward speed after an impact and the swing foot's downward speed at a strike, m/s
#: (with sqrt(g leg)); the lowest normal impulse at a strike, N s (with mass x
#: sqrt(g leg)); the torque kept below the limit, N m (with the robot's torque limit:
#: 0.02 x it)
LIFTOFF_MIN = 0.02
STRIKE_SPEED_MIN = 0.02
IMPULSE_MIN = 0.5
TORQUE_MARGIN = 3.0
#: the fields :meth:`TranscriptionSettings.for_model` fills, when none is given, with the
#: constant above times the robot's scale of that kind
_LEG_SCALED = dict(clearance_scale=CLEARANCE_SCALE, clearance_mid=CLEARANCE_MID,
                   strike_front_min=STRIKE_FRONT_MIN, lift_scale=LIFT_SCALE)
_SCALED = dict({name: ("length", v) for name, v in _LEG_SCALED.items()},
               liftoff_min=("speed", LIFTOFF_MIN), strike_speed_min=("speed", STRIKE_SPEED_MIN),
               impulse_min=("impulse", IMPULSE_MIN), torque_margin=("torque", TORQUE_MARGIN))
#: the filled fields that must be >= 0 and those that must be > 0 (units of rows)
_NONNEGATIVE = ("torque_margin", "impulse_min", "liftoff_min", "strike_speed_min",
                "clearance_mid")
_POSITIVE = ("clearance_scale", "lift_scale")


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
    torque_limit : float, tuple of float or None
        N m (with the margin below), one bound for every torque or one per torque u1 ..
        u_nu; None (the default): the robot's own (``model.description.torque_bound``:
        RABBIT 150 N m, each joint's limit where the joints' limits differ), filled in by
        :meth:`for_model`.  The co-design passes its verification's limit (the robot's
        own when it gives none).
    torque_margin : float or None
        N m kept below the torque limit (peaks between the NLP's nodes); None (the
        default): 0.02 x the robot's own torque limit (RABBIT: 3 N m; a robot without
        one: RABBIT's 3 N m times its weight x leg length over RABBIT's; a robot whose
        joints' limits differ: 0.02 x the smallest, kept below every joint's limit),
        filled in by :meth:`for_model`.
    mu_margin : float
        Kept below mu in every cone.
    normal_force_min : float
        Lowest stance normal force, fraction of the weight.
    impulse_min : float or None
        Lowest normal impulse at a strike, N s; None (the default): RABBIT's 0.5 N s
        times the robot's mass x sqrt(g leg) over RABBIT's, filled in by
        :meth:`for_model`.
    liftoff_min, strike_speed_min : float or None
        m/s: the old stance foot's upward speed after an impact, the swing foot's
        downward speed at a strike; None (the default): RABBIT's 0.02 m/s times the
        robot's sqrt(g leg) over RABBIT's, filled in by :meth:`for_model`.
    strike_front_min : float or None
        m: the strike lands at least this far in front of the stance foot; None (the
        default): 0.025 x the robot's leg length (RABBIT: 0.02 m), filled in by
        :meth:`for_model`.
    den_margin : float
        The eq. 24 denominator keeps its sign and at least this fraction of its largest
        magnitude on the reference (the walker stops at 0.01).
    clearance_mid : float or None
        m: swing-foot height kept between 0.1 T and 0.9 T (above 0 elsewhere); None (the
        default): 0.00125 x the robot's leg length (RABBIT: 0.001 m), filled in by
        :meth:`for_model`.
    clearance_scale : float or None
        m: the mid-step clearance row's unit (its aggregation's sharpness is
        ``ks_rho`` in this unit); None (the default): 0.0625 x the robot's leg length
        (RABBIT: 0.05 m), filled in by :meth:`for_model` (the transcription does).
    lift_scale : float or None
        m per unit of tau / T: between the impact and 0.1 T the swing foot's height at
        tau is kept above 0 in units of ``lift_scale x tau / T`` (the lift-off row's
        scale); None (the default): 0.375 x the robot's leg length (RABBIT: 0.3 m),
        filled in by :meth:`for_model`.
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
    torque_limit: float | tuple | None = None
    torque_margin: float | None = None
    mu_margin: float = 0.02
    normal_force_min: float = 0.05
    impulse_min: float | None = None
    liftoff_min: float | None = None
    strike_speed_min: float | None = None
    strike_front_min: float | None = None
    den_margin: float = 0.03
    clearance_mid: float | None = None
    clearance_scale: float | None = None
    lift_scale: float | None = None
    chunk: int = 10
    ks_rho: float = 300.0
    threads: int = 2

    def __post_init__(self):
        for name in _NONNEGATIVE + _POSITIVE + ("strike_front_min",):
            if getattr(self, name) is not None:
                object.__setattr__(self, name, as_number(
                    getattr(self, name), name, nonnegative=name in _NONNEGATIVE,
                    positive=name in _POSITIVE))

    def for_model(self, model) -> "TranscriptionSettings":
        """These settings with the robot's defaults filled in.

        Each only when none is given: ``torque_limit`` the robot's own; the lengths
        ``clearance_scale``, ``clearance_mid``, ``strike_front_min`` and ``lift_scale``
        RABBIT's (:data:`CLEARANCE_SCALE`, :data:`CLEARANCE_MID`,
        :data:`STRIKE_FRONT_MIN`, :data:`LIFT_SCALE`) times the robot's leg length over
        0.8 m (:func:`gait_opt.leg_scale`); the speeds ``liftoff_min`` and
        ``strike_speed_min`` (:data:`LIFTOFF_MIN`, :data:`STRIKE_SPEED_MIN`) times its
        sqrt(g leg) over RABBIT's; ``impulse_min`` (:data:`IMPULSE_MIN`) times its mass x
        sqrt(g leg) over RABBIT's; ``torque_margin`` (:data:`TORQUE_MARGIN`) times its
        torque limit over RABBIT's
        (:func:`~analysis.design.codesign.scales.physical_scales`).  On RABBIT every
        factor is exactly 1.0, so its settings are the constants bit for bit.

        Parameters
        ----------
        model : BipedModel
            The robot.

        Returns
        -------
        TranscriptionSettings
        """
        k = physical_scales(model)
        fill = {name: value * k[kind] for name, (kind, value) in _SCALED.items()
                if getattr(self, name) is None}
        if self.torque_limit is None:
            bound = model.description.torque_bound
            fill["torque_limit"] = bound if isinstance(bound, tuple) else float(bound)
        return replace(self, **fill) if fill else self


# ------------------------------------------------------------------ compiled functions
def compiled(f: ca.Function, flags: str = "-O1") -> ca.Function:
    """``f`` compiled and kept in the cache folder, by default at -O1.

    The node is large, and -O2 compiles it much longer for little.

    Parameters
    ----------
    f, flags
        As :func:`biped_casadi.numerics.compiled`.

    Returns
    -------
    casadi.Function
    """
    return _compiled(f, flags)


def _ks(v, rho):
    """Kreisselmeier-Steinhauser upper bound of max(v) along axis 0 and its weights."""
    m = v.max(axis=0)
    e = np.exp(rho * (v - m))
    s = e.sum(axis=0)
    return m + np.log(s) / rho, e / s


#: the C optimisation of the node's four-lane kernel: at -O0 the gait-fixed node compiles
#: in about 1 s and runs about 3 times faster than the scalar node (at -O1: 4 s, 12
#: times); the free-gait node (31 gait columns) in 2 s, 5 times faster (at -O1: 40 s, the
#: register allocation of one long function, 20 times).  In a run the compile dominates.
NODE_OPTIMISATION = "-O0"


@dataclass(frozen=True)
class NodeFunctions:
    """The RK4 node of :func:`_node_functions`: its four-lane kernel
    (:class:`biped_casadi.simd.AccumulatedMap`, the scenarios of a step walked over all
    their nodes in one call), or, where no kernel can be built, the compiled scalar
    Function."""

    kernel: object
    scalar: object


def _node_kinds(nG: int) -> list:
    """The kinds of the node's inputs after the accumulated (x, S): tau and R3 per node,
    h one value, (dR3 per node, free gait), P per scenario, dP one value, dth per node."""
    return ["node", "const", "node"] + (["node"] if nG else []) + ["sample", "const", "node"]


@cached(maxsize=4)
def _node_functions(model, nG: int) -> NodeFunctions:
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
    ks = kernels({"node": (f, 2, _node_kinds(nG))}, f"codesign_node_{nG}", NODE_OPTIMISATION)
    if ks is not None:
        return NodeFunctions(ks["node"], None)
    return NodeFunctions(None, compiled(f))


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

