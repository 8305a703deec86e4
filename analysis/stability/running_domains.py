"""The domains of the running stride map (:mod:`analysis.stability.running_cycle`): the
stance with the foot pinned, the foot sliding and sticking again under either law
(:func:`ground_domains`), the push-off with the foot pinned (the model without sliding)
and the flight.

Every domain takes the gains k = (Kp, Kd, M1) as its first parameters, set at entry by a
start Function that :func:`starts` builds again at other gains
(:meth:`~analysis.stability.running_cycle.RunningCycle.retuned`).  A domain under a
law with a clock (all but the pinned stance) has that clock at entry as its last
parameter; a sliding domain has the slip's sign before it, and before that whether the
slide began at rest.
"""
from __future__ import annotations

from functools import partial

import casadi as ca
import numpy as np

from .hybrid_cycle import Domain

__all__ = ["stance_domain", "slide_domain", "stick_domain", "ground_domains",
           "pushoff_domain", "flight_domain", "start", "slide_start", "SLIP_STOP", "ON_GROUND",
           "GROUND_PHASES", "FZ_PART", "SLIP_PART"]

#: the sliding foot's velocity against the friction force (must stay >= 0 in the last
#: slide under a law, which has no stick after it)
SLIP_STOP = ("slip velocity (the sliding foot stops again before takeoff: stick-slip beyond "
             "slide -> stick -> slide under one law not modelled)")

#: the foot's states on the ground after the pinned stance, under each law, in order
GROUND_PHASES = ("slide", "stick", "slide")

#: the parts of a slide's guard (:func:`slide_domain`): the sliding foot's normal force
#: reaching 0 (the takeoff, or the law's switch) and its slip stopping
FZ_PART, SLIP_PART = "sliding foot's normal force", "slip velocity"

#: the slip guard's ramp over the first RK4 step of a slide begun at rest, m/s
_V_RAMP = 1.0

#: the constraints while the stance foot is pinned on the ground, after its normal force
ON_GROUND = ("friction cone (Fx <= mu Fz)", "friction cone (-Fx <= mu Fz)",
             "swing foot height")


def _phase_constraints(c, u, extra, names):
    """The torque limit (without saturation; a robot without one has none) after the
    phase's own constraints."""
    lim = c.torque_limit                    # one number, or one per torque
    if c.saturate or not np.all(np.isfinite(lim)):
        return extra, names
    nu = c.model.nu
    each = [lim] * nu if np.ndim(lim) == 0 else list(lim)
    if np.ndim(lim):
        lim = ca.DM(each)
    cons = ca.vertcat(extra, lim - u, lim + u)
    return cons, names + tuple(f"torque u{i + 1} <= {each[i]:g} N m" for i in range(nu)) \
        + tuple(f"torque u{i + 1} >= -{each[i]:g} N m" for i in range(nu))


def start(n: int, gains, clock_origin: float | None = None) -> ca.Function:
    """Entry of a domain: X0 = x, p = the gains; with ``clock_origin`` (the domains under
    the flight law), also the law's clock at entry, s - ``clock_origin`` (s the time since
    the domain's ``clock_from`` entry: the switch to the flight law, or the landing)."""
    x = ca.SX.sym("x", n)
    k = ca.DM(np.asarray(gains, float))
    if clock_origin is None:
        return ca.Function("running_start", [x], [x, k])
    s = ca.SX.sym("s")
    return ca.Function("running_start", [x, s], [x, ca.vertcat(k, s - clock_origin)])


def _law(c, phase: str, qe, dqe, t, k):
    """The law's torques at a flight-coordinate state (the stance law sees q, dq)."""
    nq = c.model.nq
    if phase == "stance":
        return c.stance_law_k(qe[:nq], dqe[:nq], t, k)
    return c.flight_law_k(qe, dqe, t, k)


def slide_start(c, phase: str, gains, clock_origin: float) -> ca.Function:
    """Entry of a sliding domain: X0 = x; p = (the gains, rest, the slip's sign sigma,
    the law's clock at entry).  The friction force on the foot is sigma mu Fz: sigma is
    -sign of the foot's velocity, or, with the foot at rest (rest = 1, else 0), the sign
    of the tangential force the pinned foot needs there (the slip starts against it)."""
    fl, nq, ne = c.fl, c.model.nq, c.fl.ne
    x, s = ca.SX.sym("x", 2 * ne), ca.SX.sym("s")
    k = ca.DM(np.asarray(gains, float))
    qe, dqe = x[:ne], x[ne:]
    tau = s - clock_origin
    _, Fx = fl.takeoff_guard(qe[:nq], dqe[:nq], c.applied(_law(c, phase, qe, dqe, tau, k)))
    v = dqe[nq]
    sigma = ca.if_else(v != 0, -ca.sign(v), ca.sign(Fx))
    rest = ca.if_else(v != 0, 0, 1)
    return ca.Function("sliding_start", [x, s], [x, ca.vertcat(k, rest, sigma, tau)])


def stance_domain(c, mu, slack, h, t_max, tolerance, sliding: bool) -> Domain:
    """The stance, the foot pinned, under the stance law: guard the normal force, or with
    ``sliding`` the cone's margin mu Fz - ``|Fx|`` (the foot starts to slide where it
    reaches 0; reset ``takeoff`` into the flight coordinates)."""
    m, fl, nq, nu = c.model, c.fl, c.model.nq, c.model.nu
    X, t, k = ca.SX.sym("X", 2 * nq), ca.SX.sym("t"), ca.SX.sym("k", 3 * nu)
    q, dq = X[:nq], X[nq:]
    u = c.stance_law_k(q, dq, t, k)
    ua = c.applied(u)
    Fz, Fx = fl.takeoff_guard(q, dq, ua)
    cons, names = _phase_constraints(
        c, u, ca.vertcat(Fz, *_on_ground(m, mu, slack, q, Fz, Fx)),
        ("stance normal force",) + ON_GROUND)
    x = ca.SX.sym("x", 2 * nq)
    if sliding:
        guard, gname = mu * Fz - ca.fabs(Fx), "friction margin mu Fz - |Fx|"
        reset = ca.Function("to_slide", [x], [ca.vertcat(*fl.takeoff(x[:nq], x[nq:]))])
    else:
        guard, gname = Fz, "stance normal force"
        reset = ca.Function("switch", [x], [x])
    return Domain("stance", 2 * nq, ca.Function("running_stance", [X, t, k],
                                                [ca.vertcat(dq, m.forward_dynamics(q, dq, ua))]),
                  ca.Function("stance_guard", [X, t, k], [guard]), reset, h, t_max,
                  start=start(2 * nq, c.gains),
                  constraints=ca.Function("stance_constraints", [X, t, k], [cons]),
                  constraint_names=names, guard_name=gname, tolerance=tolerance,
                  dense_constraints=names, dense_guard=True,
                  common_subexpressions=False)


def _on_ground(m, mu, slack, q, Fz, Fx) -> tuple:
    """The friction cone with its slack and the swing foot's height (:data:`ON_GROUND`)."""
    return mu * Fz - Fx + slack, mu * Fz + Fx + slack, m.swing_foot(q)[1]


def slide_domain(c, phase: str, mu, h, t_max, tolerance, origin, clock_from,
                 name: str, after: int = 0) -> Domain:
    """The stance foot sliding under a phase's law (``fl.sliding_dynamics``, the
    friction force sigma mu Fz); empty where Fz <= 0 at entry.

    The last slide under a law (``after`` = 0): guard the normal force (the takeoff, or
    the law's switch); constraints the slip against the friction force
    (:data:`SLIP_STOP`), the swing foot's height and the torque limit; reset the
    identity.  A slide before ``after`` more domains under the law (a stick, a slide):
    a guard of two parts, the normal force (the takeoff or the switch: the identity,
    and the ``after`` domains skipped) and the slip velocity against the friction
    force (the slip stops: its velocity set to 0, the stick next); a slide begun at
    rest adds to the slip's part a ramp from ``_V_RAMP`` at entry to 0 at the first RK4
    node (the slip starts from 0 there, and has not stopped); the same constraints (the
    slip's would bind only for a slip begun at rest that reverses within its first step).
    Rest and sigma are the domain's discrete parameters: a slide the other way is
    another piece of the stride map (``Domain.discrete_parameters``).
    """
    fl, nq, ne, nu = c.fl, c.model.nq, c.fl.ne, c.model.nu
    Y, t, p = ca.SX.sym("Y", 2 * ne), ca.SX.sym("t"), ca.SX.sym("p", 3 * nu + 3)
    qe, dqe = Y[:ne], Y[ne:]
    u = _law(c, phase, qe, dqe, t + p[-1], p[:3 * nu])
    rest, sigma = p[3 * nu], p[3 * nu + 1]
    ddqe, Fz = fl.sliding_dynamics(qe, dqe, c.applied(u), sigma * mu)
    slip = -sigma * dqe[nq]
    cons, names = _phase_constraints(c, u, ca.vertcat(slip, fl.feet(qe)[1, 1]),
                                     (SLIP_STOP, "swing foot height"))
    y = ca.SX.sym("y", 2 * ne)
    end = ca.Function("slide_end", [y], [y])
    parts = (FZ_PART, SLIP_PART)
    if after == 0:
        guard, gname, parts, skip = Fz, FZ_PART, parts[:1], (0,)
    else:
        guard = ca.vertcat(Fz, slip + rest * _V_RAMP * ca.fmax(0, 1 - t / h))
        gname = "sliding foot's normal force or slip velocity"
        stop = ca.vertcat(y[:ne + nq], 0, y[ne + nq + 1:])
        end, skip = (end, ca.Function("slip_stop", [y], [stop])), (after, 0)
    return Domain(name, 2 * ne, ca.Function(f"running_{phase}_slide", [Y, t, p],
                                            [ca.vertcat(dqe, ddqe)]),
                  ca.Function("slide_guard", [Y, t, p], [guard]), end, h, t_max,
                  start=slide_start(c, phase, c.gains, origin),
                  constraints=ca.Function("slide_constraints", [Y, t, p], [cons]),
                  constraint_names=names, guard_name=gname, guard_parts=parts, skip=skip,
                  tolerance=tolerance, dense_constraints=names, dense_guard=True,
                  common_subexpressions=False, clock_from=clock_from, may_be_empty=True,
                  discrete_parameters=(3 * nu, 3 * nu + 1))       # rest and sigma


def stick_domain(c, phase: str, mu, h, t_max, tolerance, origin, clock_from,
                 name: str) -> Domain:
    """The stance foot stuck again where its slip stopped, under a phase's law: the
    pinned dynamics in the flight coordinates (the foot where it stopped); guard the
    cone's margin mu Fz - ``|Fx|`` (it slides again where that reaches 0; Fz cannot
    vanish first); constraints Fz, the swing foot's height and the torque limit; reset
    the identity.  Skipped where the slide before ended at the takeoff or the law's
    switch (its normal force's part, :func:`slide_domain`); empty where the margin is
    <= 0 at entry: the pinned foot would need more than mu Fz the other way, and the next
    slide starts against it."""
    m, fl, nq, ne, nu = c.model, c.fl, c.model.nq, c.fl.ne, c.model.nu
    Y, t, p = ca.SX.sym("Y", 2 * ne), ca.SX.sym("t"), ca.SX.sym("p", 3 * nu + 1)
    qe, dqe = Y[:ne], Y[ne:]
    q, dq = qe[:nq], dqe[:nq]
    u = _law(c, phase, qe, dqe, t + p[-1], p[:3 * nu])
    ua = c.applied(u)
    Fz, Fx = fl.takeoff_guard(q, dq, ua)
    cons, names = _phase_constraints(c, u, ca.vertcat(Fz, fl.feet(qe)[1, 1]),
                                     ("stance normal force", "swing foot height"))
    guard = mu * Fz - ca.fabs(Fx)
    y = ca.SX.sym("y", 2 * ne)
    return Domain(name, 2 * ne, ca.Function(f"running_{phase}_stick", [Y, t, p],
                                            [ca.vertcat(dqe, m.forward_dynamics(q, dq, ua),
                                                        ca.SX.zeros(2))]),
                  ca.Function("stick_guard", [Y, t, p], [guard]),
                  ca.Function("stick_end", [y], [y]), h, t_max,
                  start=start(2 * ne, c.gains, origin),
                  constraints=ca.Function("stick_constraints", [Y, t, p], [cons]),
                  constraint_names=names, guard_name="friction margin mu Fz - |Fx|",
                  tolerance=tolerance, dense_constraints=names, dense_guard=True,
                  common_subexpressions=False,
                  clock_from=clock_from, may_be_empty=True)


def ground_domains(c, phase: str, mu, h, t_max, tolerance, origin, clock_from,
                   names) -> tuple:
    """The stance foot on the ground under a phase's law after the pinned stance
    (:data:`GROUND_PHASES`): slide, stick again where the slip stops, slide again to
    Fz = 0 (its slip must not stop: :data:`SLIP_STOP`).  ``names`` one per domain.

    Returns
    -------
    tuple
        (the domains, their starts at given gains).
    """
    last = len(GROUND_PHASES) - 1
    doms, starts = [], []
    for i, (kind, name) in enumerate(zip(GROUND_PHASES, names)):
        if kind == "slide":
            doms.append(slide_domain(c, phase, mu, h, t_max, tolerance, origin, clock_from,
                                     name, after=last - i))
            starts.append(partial(slide_start, c, phase, clock_origin=origin))
        else:
            doms.append(stick_domain(c, phase, mu, h, t_max, tolerance, origin, clock_from,
                                     name))
            starts.append(partial(start, 2 * c.fl.ne, clock_origin=origin))
    return doms, starts


def pushoff_domain(c, mu, slack, h, t_max, tolerance, origin, clock_from) -> Domain:
    """The push-off without sliding (module docstring of
    :mod:`~analysis.stability.running_cycle`): the stance foot pinned under the flight
    law, while the ground still pushes it."""
    m, fl, nq, nu = c.model, c.fl, c.model.nq, c.model.nu
    X, t = ca.SX.sym("X", 2 * nq), ca.SX.sym("t")
    q, dq = X[:nq], X[nq:]
    kf = ca.SX.sym("k", 3 * nu + 1)              # the gains, then the law's clock at the switch
    qe, dqe = fl.takeoff(q, dq)
    u = c.flight_law_k(qe, dqe, t + kf[-1], kf[:-1])
    ua = c.applied(u)
    Fz, Fx = fl.takeoff_guard(q, dq, ua)
    cons, names = _phase_constraints(c, u, ca.vertcat(*_on_ground(m, mu, slack, q, Fz, Fx)),
                                     ON_GROUND)
    x = ca.SX.sym("x", 2 * nq)
    qe, dqe = fl.takeoff(x[:nq], x[nq:])
    return Domain("push-off", 2 * nq,
                  ca.Function("running_pushoff", [X, t, kf],
                              [ca.vertcat(dq, m.forward_dynamics(q, dq, ua))]),
                  ca.Function("normal_force", [X, t, kf], [Fz]),
                  ca.Function("takeoff", [x], [ca.vertcat(qe, dqe)]), h, t_max,
                  start=start(2 * nq, c.gains, origin),
                  constraints=ca.Function("pushoff_constraints", [X, t, kf], [cons]),
                  constraint_names=names, guard_name="stance normal force",
                  tolerance=tolerance, dense_constraints=names, dense_guard=True,
                  common_subexpressions=False,
                  clock_from=clock_from, may_be_empty=True)


def flight_domain(c, mu, h, t_max, tolerance, origin, clock_from) -> Domain:
    """The flight under the flight law, to the swing foot's landing (module docstring of
    :mod:`~analysis.stability.running_cycle`)."""
    fl, nu, ne = c.fl, c.model.nu, c.fl.ne
    t = ca.SX.sym("t")
    Y = ca.SX.sym("Y", 2 * ne)
    qe, dqe = Y[:ne], Y[ne:]
    kf = ca.SX.sym("k", 3 * nu + 1)              # the gains, then the law's clock at entry
    uf = c.flight_law_k(qe, dqe, t + kf[-1], kf[:-1])
    f_fl = ca.Function("running_flight", [Y, t, kf],
                       [ca.vertcat(dqe, fl.flight_dynamics(qe, dqe, c.applied(uf)))])
    feet = fl.feet(qe)
    g_fl = ca.Function("swing_foot_height", [Y, t, kf], [feet[1, 1]])
    cons, names = _phase_constraints(c, uf, feet[1, 0], ("other foot height",))
    c_fl = ca.Function("flight_constraints", [Y, t, kf], [cons])
    y = ca.SX.sym("y", 2 * ne)
    qp, dqp, F, _, v_other, _ = fl.landing_swing(y[:ne], y[ne:])
    r_fl = ca.Function("landing", [y], [ca.vertcat(qp, dqp)])
    e_fl = ca.Function("landing_checks", [y],
                       [ca.vertcat(F[1], mu * F[1] - F[0], mu * F[1] + F[0], v_other[1])])
    return Domain("flight", 2 * ne, f_fl, g_fl, r_fl, h, t_max,
                  start=start(2 * ne, c.gains, origin), constraints=c_fl,
                  constraint_names=names,
                  exit_constraints=e_fl,
                  exit_constraint_names=("landing normal impulse",
                                         "landing impulse in the cone (Fx <= mu Fz)",
                                         "landing impulse in the cone (-Fx <= mu Fz)",
                                         "other foot's lift-off velocity"),
                  guard_name="swing foot height", tolerance=tolerance,
                  dense_constraints=names, dense_guard=True,
                  common_subexpressions=False, clock_from=clock_from)
